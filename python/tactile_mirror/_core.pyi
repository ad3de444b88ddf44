"""tactile_mirror C++ core: SOS filters, slip-detector kernel, real-time pipeline.

Type stub of the compiled module. The public API wraps it: ``SosFilter`` and ``sosfilt``
(filters.py), ``SlipDetector`` (detector/) and ``MirrorPipeline`` (pipeline.py).
Classes that differ only in their arithmetic share a generic base that exists only here
(``@type_check_only``), as do the TypedDicts of the pipeline's dict arguments and results.
"""

from collections.abc import Sequence
from typing import (
    Any,
    Generic,
    Literal,
    SupportsFloat,
    SupportsIndex,
    TypedDict,
    TypeVar,
    overload,
    type_check_only,
)

import numpy as np
import numpy.typing as npt
from typing_extensions import TypeAlias

_F = TypeVar("_F", np.float32, np.float64)
_FD = TypeVar("_FD", np.float32, np.float64)

_Activation: TypeAlias = Literal["exact", "fast"]
_DetectorPath: TypeAlias = Literal["avx2+fma", "sse2", "native", "generic"]
# "avx2" is accepted as a synonym of "avx2+fma" where a path is set.
_DetectorPathArg: TypeAlias = Literal["avx2+fma", "avx2", "sse2", "native", "generic", "baseline"]
_Isa: TypeAlias = Literal["avx2+fma", "sse2", "native", "generic"]
_ControllerKind: TypeAlias = Literal["none", "paper", "velocity"]

# ---- SOS cascade (bind_sos.cpp) ------------------------------------------------------

@type_check_only
class _SosCascade(Generic[_F]):
    def __init__(self, sos: npt.ArrayLike, channels: SupportsIndex, forms: npt.NDArray[np.uint8]) -> None:
        """sos: (n_sections, 6), normalised; forms: one code per section, 0 (tdf2) or 1 (delta)."""
    @property
    def channels(self) -> int: ...
    @property
    def sections(self) -> int: ...
    @property
    def isa(self) -> _Isa:
        """Instruction set the kernels run on."""
    @property
    def rejected(self) -> int:
        """Number of step() samples rejected as non-finite."""
    def use_baseline_isa(self) -> None:
        """Run the portable baseline kernels (testing aid)."""
    def process(
        self, x: npt.NDArray[_F], guard_state: bool = False
    ) -> tuple[npt.NDArray[_F], int, int] | tuple[None, int, int]:
        """Filter a block x (channels, n), any strides.

        Returns ``(y, -1, -1)``, or ``(None, t, c)`` at the first non-finite sample
        (sample t of channel c), leaving the state unchanged. ``guard_state``: an
        output or final state that overflows raises ValueError, state unchanged.
        """
    def step(self, sample: npt.ArrayLike) -> npt.NDArray[_F]:
        """Filter one sample (channels,) of any real dtype. A NaN/Inf sample is rejected:
        the state is kept, ``rejected`` counts it and the previous output is returned."""
    def get_state(self) -> npt.NDArray[_F]:
        """A copy of the state, shape (n_sections, channels, 2)."""
    def set_state(self, zi: npt.ArrayLike) -> None:
        """Set the state from finite values of shape (n_sections, channels, 2)."""
    def reset(self) -> None:
        """Zero the state and the rejection count."""
    def time_step(self, n_steps: SupportsIndex, thread_ftz: bool = False) -> float:
        """Benchmark: ns per step() over n_steps steps, timed in C++; the state is reset afterwards."""

class _SosCascade64(_SosCascade[np.float64]):
    """Multi-channel SOS cascade in float64. Use tactile_mirror.SosFilter instead."""

class _SosCascade32(_SosCascade[np.float32]):
    """Multi-channel SOS cascade in float32. Use tactile_mirror.SosFilter instead."""

def simd_path() -> _Isa:
    """The code variant of the SIMD layer (simd.hpp) that every C++ kernel built now runs."""

def _set_baseline(on: bool) -> None:
    """Hold every kernel of this process to the baseline variant (on=True), or return to the CPU's best."""

def _baseline_forced() -> bool:
    """Whether the kernels are held to the baseline variant now (_set_baseline, TM_SIMD=baseline)."""

# ---- Jordan MLP slip detector (bind_detector.cpp) ------------------------------------

@type_check_only
class _JordanMLP(Generic[_F]):
    def __init__(
        self,
        w1: npt.ArrayLike,
        b1: npt.ArrayLike,
        w2: npt.ArrayLike,
        b2: npt.ArrayLike,
        input_mean: npt.ArrayLike,
        input_gain: npt.ArrayLike,
        n_instances: SupportsIndex,
        activation: _Activation = "exact",
    ) -> None:
        """Weights (finite, any real dtype): w1 (n_hidden, n_inputs + 1), b1 (n_hidden,),
        w2 (2, n_hidden), b2 (2,), input_mean and input_gain (n_inputs,)."""
    @property
    def n_instances(self) -> int: ...
    @property
    def n_inputs(self) -> int: ...
    @property
    def n_hidden(self) -> int: ...
    @property
    def dtype(self) -> np.dtype[_F]: ...
    @property
    def activation(self) -> _Activation: ...
    @activation.setter
    def activation(self, value: _Activation, /) -> None: ...
    @property
    def simd_path(self) -> _DetectorPath: ...
    def set_simd_path(self, path: _DetectorPathArg) -> None:
        """Select the kernel path; ValueError if this CPU cannot run it."""
    @property
    def state(self) -> npt.NDArray[_F]:
        """y_pred(t-1) of every instance (the Jordan feedback state), shape (n_instances,)."""
    @state.setter
    def state(self, value: npt.NDArray[_F], /) -> None: ...
    def reset(self) -> None:
        """Set the feedback state to zero."""
    def step(self, x: npt.NDArray[_F]) -> npt.NDArray[_F]:
        """One tick. x: (n_instances, n_inputs) -> (n_instances, 3) [y_slip, y_non, y_pred]."""
    def step_one(self, instance: SupportsIndex, x: npt.NDArray[_F]) -> npt.NDArray[_F]:
        """One tick of one instance (scalar code). x: (n_inputs,) -> (3,) [y_slip, y_non, y_pred]."""
    def run(self, x: npt.NDArray[_F], reset: bool = False) -> npt.NDArray[_F]:
        """Run the recurrence over a block. x: (n_instances, n_inputs, n) -> (3, n_instances, n)
        [y_slip, y_non, y_pred]; the state carries over between calls (reset: from zero).
        Releases the GIL; NaN/Inf features are a ValueError naming ridge, channel, sample."""
    def time_step_ns(
        self,
        n_iter: SupportsIndex = 1000000,
        repeats: SupportsIndex = 5,
        mode: Literal["simd", "scalar"] = "simd",
    ) -> float:
        """Mean ns of one tick of all instances (best of repeats), measured in C++; 'simd' times
        step() on the selected path, 'scalar' a plain loop of step_one()."""

class JordanMLPf32(_JordanMLP[np.float32]):
    """Jordan recurrent MLP slip-detector kernel (float32), n_instances instances sharing one
    weight set. Inputs must be float32 arrays (no conversion)."""

class JordanMLPf64(_JordanMLP[np.float64]):
    """Jordan recurrent MLP slip-detector kernel (float64), n_instances instances sharing one
    weight set. Inputs must be float64 arrays (no conversion)."""

@type_check_only
class _MemoryJordan(Generic[_F]):
    def __init__(
        self,
        w1: npt.ArrayLike,
        b1: npt.ArrayLike,
        w2: npt.ArrayLike,
        b2: npt.ArrayLike,
        input_mean: npt.ArrayLike,
        input_gain: npt.ArrayLike,
        n_ridges: SupportsIndex,
        fs: float,
        tau: float,
        activation: _Activation = "exact",
    ) -> None:
        """Weights of the 8-input Jordan net (w1 (n_hidden, 9), input_mean and input_gain (8,));
        fs (Hz) and tau (s) set the leak of the load integrals."""
    @property
    def n_instances(self) -> int: ...
    @property
    def n_inputs(self) -> int: ...
    @property
    def n_hidden(self) -> int: ...
    @property
    def dtype(self) -> np.dtype[_F]: ...
    @property
    def simd_path(self) -> _DetectorPath: ...
    def set_simd_path(self, path: _DetectorPathArg) -> None:
        """Select the kernel path; ValueError if this CPU cannot run it."""
    @property
    def state(self) -> tuple[npt.NDArray[_F], npt.NDArray[_F]]:
        """(y_pred(t-1) per ridge (n_ridges,), [load, press] per ridge (n_ridges, 2))."""
    @state.setter
    def state(self, value: tuple[npt.NDArray[_F], npt.NDArray[_F]], /) -> None: ...
    def reset(self) -> None:
        """Set the feedback and load state to zero."""
    def step(self, x: npt.NDArray[_F]) -> npt.NDArray[_F]:
        """One tick. x: (n_ridges, 4) -> (n_ridges, 3) [y_slip, y_non, y_pred]."""
    def run(self, x: npt.NDArray[_F], reset: bool = False) -> npt.NDArray[_F]:
        """Run over a block. x: (n_ridges, 4, n) -> (3, n_ridges, n); the state carries over."""
    def time_step_ns(self, n_iter: SupportsIndex = 1000000, repeats: SupportsIndex = 5) -> float:
        """Mean time of one tick (feature stage and net) of all ridges, measured in C++ (ns)."""

class MemoryJordanf32(_MemoryJordan[np.float32]):
    """Load-memory slip detector of one pad (float32): load integrals and pad channels in front
    of the Jordan kernel (8 inputs). Inputs must be float32 arrays."""

class MemoryJordanf64(_MemoryJordan[np.float64]):
    """Load-memory slip detector of one pad (float64). Inputs must be float64 arrays."""

@type_check_only
class _BankJordan(Generic[_F]):
    def __init__(
        self,
        w1: npt.ArrayLike,
        b1: npt.ArrayLike,
        w2: npt.ArrayLike,
        b2: npt.ArrayLike,
        input_mean: npt.ArrayLike,
        input_gain: npt.ArrayLike,
        n_ridges: SupportsIndex,
        fs: float,
        lp_taus: npt.ArrayLike,
        abs_taus: npt.ArrayLike,
        load_tau: float,
        peak_tau: float,
        activation: _Activation = "exact",
        knee: npt.ArrayLike | None = None,
        pad_mean: bool = False,
    ) -> None:
        """Weights of the Jordan net on the bank's 4 + 2 len(lp_taus) + len(abs_taus) + 3 features
        per ridge (twice that with pad_mean: then also their mean over the ridges); fs (Hz) and
        the time constants (s) set the filters; knee (one per net input, or None): the inputs
        compressed to sign(x) log(1 + |x| / knee) (detector.bank.log_compress)."""
    @property
    def n_instances(self) -> int: ...
    @property
    def n_inputs(self) -> int: ...
    @property
    def n_features(self) -> int: ...
    @property
    def net_inputs(self) -> int:
        """The net's inputs per ridge: n_features, twice that with the pad's mean."""
    @property
    def pad_mean(self) -> bool:
        """Whether the net also reads the pad's mean of the features."""
    @property
    def compressed(self) -> bool:
        """Whether the inputs are compressed (knees given)."""
    @property
    def n_hidden(self) -> int: ...
    @property
    def dtype(self) -> np.dtype[_F]: ...
    @property
    def simd_path(self) -> _DetectorPath: ...
    def set_simd_path(self, path: _DetectorPathArg) -> None:
        """Select the kernel path; ValueError if this CPU cannot run it."""
    @property
    def state(self) -> tuple[npt.NDArray[_F], npt.NDArray[_F]]:
        """(y_pred(t-1) per ridge (n_ridges,), filter states (n_ridges, n_state))."""
    @state.setter
    def state(self, value: tuple[npt.NDArray[_F], npt.NDArray[_F]], /) -> None: ...
    def reset(self) -> None:
        """Set the feedback and filter states to zero."""
    def step(self, x: npt.NDArray[_F]) -> npt.NDArray[_F]:
        """One tick. x: (n_ridges, 4) -> (n_ridges, 3) [y_slip, y_non, y_pred]."""
    def run(self, x: npt.NDArray[_F], reset: bool = False) -> npt.NDArray[_F]:
        """Run over a block. x: (n_ridges, 4, n) -> (3, n_ridges, n); the state carries over."""
    def time_step_ns(self, n_iter: SupportsIndex = 1000000, repeats: SupportsIndex = 5) -> float:
        """Mean time of one tick (filter bank and net) of all ridges, measured in C++ (ns)."""

class BankJordanf32(_BankJordan[np.float32]):
    """Filter-bank slip detector (float32): IIR filters over the stress rates in front of the
    Jordan kernel. Inputs must be float32 arrays."""

class BankJordanf64(_BankJordan[np.float64]):
    """Filter-bank slip detector (float64). Inputs must be float64 arrays."""

# The detector kernel's sigmoid (with its clamp) on a flat copy of a, in a's dtype (float32 or
# float64, else TypeError); for error measurements.
@overload
def detector_sigmoid(  # type: ignore[overload-overlap]
    a: npt.NDArray[np.float32], activation: _Activation = "fast", path: _DetectorPathArg = "avx2+fma"
) -> npt.NDArray[np.float32]: ...
@overload
def detector_sigmoid(
    a: npt.NDArray[np.float64], activation: _Activation = "fast", path: _DetectorPathArg = "avx2+fma"
) -> npt.NDArray[np.float64]: ...
def detector_cpu_has_avx2_fma() -> bool:
    """True if the kernels' AVX2+FMA variant can run now (this CPU and build have one, no baseline switch)."""

def jordan_loss_grad(
    theta: npt.NDArray[np.float64],
    xn: npt.NDArray[np.float64],
    t_slip: npt.NDArray[np.float64],
    t_pred: npt.NDArray[np.float64],
    w_slip: npt.NDArray[np.float64],
    w_pred: npt.NDArray[np.float64],
    length: npt.NDArray[np.integer[Any]],
    n_hidden: int,
    n_threads: int = 1,
) -> tuple[float, npt.NDArray[np.float64]]:
    """Weighted cross-entropy loss of the Jordan net and its exact BPTT gradient (float64)."""

# ---- real-time pipeline (bind_pipeline.cpp) ------------------------------------------

@type_check_only
class _ControllerParams(TypedDict, total=False):
    """Controller parameters; every key is optional on input and present on output."""

    kind: _ControllerKind
    threshold: float
    gain: float
    y_full: float
    v_max: float
    a_max: float
    x_min: float
    x_max: float
    direction_sign: float
    asym_tau: float
    asym_deadband: float
    shear_gain: float
    arm_delay: float
    ramp_gain: float
    pred_boost: float
    slip_hold: float
    shear_integral: float
    rate_gain: float
    slip_confirm: float
    slip_min_asym: float
    planner_decel: float

@type_check_only
class _ControllerState(TypedDict):
    position: float
    command: float
    velocity: float
    asymmetry: float
    direction: float

@type_check_only
class _PipelineStatus(TypedDict):
    ticks: int
    rejected: int
    nonfinite: int
    out_of_range: int
    overflow: int
    last_bad_tick: int
    last_bad_channel: int
    consecutive_rejected: int
    fault: bool
    slip: bool
    at_limit: bool
    last_reason: str

@type_check_only
class _PipelineDefaults(TypedDict):
    v_limit: float
    u_limit: float
    slip_threshold: float
    max_hold_ticks: int
    force_limit: float

def controller_fields() -> list[tuple[str, tuple[str, ...], str]]:
    """The controller parameters, in order: (name, laws that read it, meaning)."""
def controller_defaults(kind: str) -> _ControllerParams:
    """Default parameters of a law ('none', 'paper' or 'velocity')."""
def pipeline_defaults() -> _PipelineDefaults:
    """Defaults shared with the C ABI (v_limit, u_limit: the front end's output swing, V;
    force_limit: a load cell's range, N)."""

@type_check_only
class _MirrorPipeline(Generic[_F, _FD]):
    def __init__(
        self,
        n_ridges: SupportsIndex,
        fs: SupportsFloat,
        use_u: bool,
        sos_v: npt.ArrayLike | None,
        sos_u: npt.ArrayLike | None,
        sos_diff: npt.ArrayLike | None,
        v_limit: SupportsFloat,
        u_limit: SupportsFloat,
        w1: npt.ArrayLike,
        b1: npt.ArrayLike,
        w2: npt.ArrayLike,
        b2: npt.ArrayLike,
        input_mean: npt.ArrayLike,
        input_gain: npt.ArrayLike,
        weights_fs: SupportsFloat,
        activation: _Activation,
        slip_threshold: SupportsFloat,
        max_hold_ticks: SupportsIndex,
        controller: _ControllerParams,
        shear_weights: npt.ArrayLike | None = None,
        bank: dict[str, Any] | None = None,
        force_input: bool = False,
        force_limit: float = 100.0,
    ) -> None:
        """Build the pipeline; see tactile_mirror.pipeline.pipeline_config for the arguments.
        Filters (sos_*) are None or (n_sections, 6); w1 is (n_hidden, nf + 1) with nf = 4, or
        the filter bank's input count when bank (lp_taus, abs_taus, load_tau, peak_tau) is
        given; shear_weights None or (n_ridges, 2)."""
    @property
    def n_ridges(self) -> int: ...
    @property
    def n_inputs(self) -> int: ...
    @property
    def n_outputs(self) -> int: ...
    @property
    def fs(self) -> float: ...
    @property
    def use_u(self) -> bool: ...
    @property
    def force_input(self) -> bool: ...
    @property
    def detector_kind(self) -> int:
        """0: the paper's net; 1: the filter-bank net."""
    @property
    def n_detector_inputs(self) -> int: ...
    @property
    def dtype(self) -> np.dtype[_F]:
        """Arithmetic of the filters."""
    @property
    def detector_dtype(self) -> np.dtype[_FD]:
        """Arithmetic of the detector."""
    @property
    def simd_path(self) -> str:
        """``"filters <isa>, detector <path>"``."""
    @property
    def controller(self) -> _ControllerParams: ...
    def step(self, x: npt.NDArray[np.float64], out: npt.NDArray[np.float64] | None = None) -> float:
        """One tick. x: float64 (n_inputs,) C-contiguous, no conversion; out: float64 (n_outputs,)
        receives [x_cmd, v_cmd, y_slip_0, y_non_0, y_pred_0, ...]. Returns x_cmd (m). A NaN/Inf or
        out-of-range sample rejects the tick (counted in status; detector outputs held)."""
    @overload
    def process_block(
        self, x: npt.ArrayLike, features: Literal[False] = False, accepted: Literal[False] = False
    ) -> tuple[npt.NDArray[np.float64]]: ...
    @overload
    def process_block(
        self, x: npt.ArrayLike, features: Literal[True], accepted: Literal[False] = False
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    @overload
    def process_block(
        self, x: npt.ArrayLike, features: Literal[False] = False, *, accepted: Literal[True]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]: ...
    @overload
    def process_block(
        self, x: npt.ArrayLike, features: Literal[False], accepted: Literal[True]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]: ...
    @overload
    def process_block(
        self, x: npt.ArrayLike, features: Literal[True], accepted: Literal[True]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]: ...
    @overload
    def process_block(
        self, x: npt.ArrayLike, features: bool = False, accepted: bool = False
    ) -> tuple[npt.NDArray[Any], ...]: ...
    @property
    def outputs(self) -> npt.NDArray[np.float64]:
        """Live read-only view of the last outputs (n_outputs,)."""
    @property
    def features(self) -> npt.NDArray[np.float64]:
        """Features of the last accepted tick, (n_ridges, 4) [rate_L, rate_R, rate2_L, rate2_R]."""
    @property
    def last_accepted(self) -> bool: ...
    @property
    def status(self) -> _PipelineStatus: ...
    @property
    def controller_state(self) -> _ControllerState: ...
    def reset(self, x0: SupportsFloat = 0.0) -> None:
        """Zero filters, detector state and status; the command starts at x0 (m, clamped)."""
    def set_position(self, x: SupportsFloat) -> None:
        """Move the commanded position to x (m, clamped to the travel limits) and stop."""
    def time_step_ns(self, n_iter: SupportsIndex = 200000, repeats: SupportsIndex = 5) -> float:
        """Mean ns of one tick measured inside C++ over n_iter ticks (best of repeats); state restored."""

class _MirrorPipelineF64(_MirrorPipeline[np.float64, np.float64]):
    """Real-time tactile-mirror pipeline, float64 filters and detector (see tactile_mirror.MirrorPipeline)."""

class _MirrorPipelineF32(_MirrorPipeline[np.float32, np.float32]):
    """Real-time tactile-mirror pipeline, float32 filters and detector (see tactile_mirror.MirrorPipeline)."""

class _MirrorPipelineF64F32(_MirrorPipeline[np.float64, np.float32]):
    """Real-time tactile-mirror pipeline, float64 filters and float32 detector (see tactile_mirror.MirrorPipeline)."""

# ---------------------------------------------------------------- contact solver (contact_solver.hpp)
class _ContactSolver:
    """Condensed contact solver of one ridge. Use tactile_mirror.contact.ContactSolver."""

    def __init__(
        self, compliance: npt.ArrayLike, node_z: npt.ArrayLike, weights: npt.ArrayLike, r: float, w_tol: float
    ) -> None: ...
    @property
    def n_nodes(self) -> int: ...
    @property
    def r(self) -> float: ...
    @property
    def factorizations(self) -> int:
        """Piece LU factorisations since construction."""
    @property
    def affine_steps(self) -> int:
        """Piece solves served by the affine response of an unchanged piece."""
    @property
    def rhs_reuses(self) -> int:
        """Base solves of a load's right-hand side served by the previous one (the iterations of one load point)."""
    @property
    def updates(self) -> int:
        """Pieces solved by bordering the factored base piece instead of refactoring."""
    def set_params(
        self, mu: float, mu_kinetic: float, tol: float, max_iter: int, max_active_set_iter: int
    ) -> None: ...
    def step(
        self, plate_y: float, plate_z: float, every: bool = True
    ) -> tuple[int, npt.NDArray[np.float64] | None, npt.NDArray[np.float64] | None, npt.NDArray[np.int8] | None,
               float, int]:
        """(status, forces, displacement, state, slip_fraction, solves); arrays None unless status is 0."""
    def error(self) -> tuple[int, float, float]:
        """(info, residual, tolerance) of the last failed step."""
    def error_point(self) -> tuple[float, float]:
        """Load point (plate_y, plate_z) of the last failure inside follow."""
    @property
    def solves(self) -> int:
        """Linear solves of the path following since the last reset."""
    @property
    def events(self) -> int:
        """Points where node statuses changed since the last reset."""
    def set_event_tolerances(self, g_tol: float, f_tol: float, evt_g_tol: float, evt_f_tol: float) -> None: ...
    def follow(
        self,
        plate_y: npt.ArrayLike,
        plate_z: npt.ArrayLike,
        every: bool,
        lam_out: npt.NDArray[np.float64] | None,
        u_out: npt.NDArray[np.float64] | None,
        state_out: npt.NDArray[np.int8] | None,
    ) -> tuple[int, int, int]:
        """Event-driven path following over N samples without the GIL; (status, solves, events)."""
    def reset(self) -> None: ...
    def get_history(self) -> dict[str, Any]: ...
    def set_history(
        self, lam: npt.ArrayLike, uy_prev: npt.ArrayLike, s_prev: float, state: npt.ArrayLike, sign: npt.ArrayLike,
        sliding: npt.ArrayLike, z_prev: float | None = None,
    ) -> None: ...

class _ContactPad:
    """Ridges of a pad stepped in one call without the GIL. Use tactile_mirror.contact.Pad."""

    def __init__(self, solvers: Sequence[_ContactSolver]) -> None: ...
    @property
    def n_ridges(self) -> int: ...
    def step(
        self, plate_y: float, plate_z: npt.ArrayLike, every: bool = True, threads: int = 1
    ) -> tuple[int, int, int, npt.NDArray[np.float64] | None, npt.NDArray[np.float64] | None,
               npt.NDArray[np.int8] | None, npt.NDArray[np.float64] | None, npt.NDArray[np.bool_] | None,
               npt.NDArray[np.bool_] | None, float, float]:
        """(status, failing ridge, iterations, forces, displacement, state, slip_fraction, touching,
        gross_slip, sum of f_t, sum of f_n); committed only if all converged."""
    @property
    def sources(self) -> tuple[int, ...]:
        """Of the last call, per ridge: the ridge whose results it got (itself, or the earlier
        ridge with the same configuration, history and plate path it shadows)."""
    def follow(
        self,
        plate_y: npt.ArrayLike,
        plate_z: npt.ArrayLike,
        every: bool,
        lam: npt.NDArray[np.float64] | None,
        displacement: npt.NDArray[np.float64] | None,
        state: npt.NDArray[np.int8] | None,
        slip_fraction: npt.NDArray[np.float64] | None,
        threads: int = 1,
        proj: npt.ArrayLike | None = None,
        proj_out: npt.NDArray[np.float64] | None = None,
        flags: npt.NDArray[np.int8] | None = None,
    ) -> tuple[int, int, int, int]:
        """Every ridge follows the whole trajectory (on 1 or 2 threads) into preallocated arrays
        (forces lam = (lt, ln); with proj (q, 2n), proj_out gets proj @ lam per sample; flags:
        bit 0 touching, bit 1 gross slip); returns (status, failing ridge, solves, events)."""

def _contact_simd_path() -> str:
    """The variant the contact kernels run now, by simd_path()'s names: 'avx2+fma' or the base variant."""
