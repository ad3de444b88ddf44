// Cascades of second-order sections, many channels at once.
//
// SosCascade<T> runs the same cascade on `channels` independent signals. Channels
// are packed into 32-byte vectors (4 doubles / 8 floats), so one instruction
// advances 4 or 8 channels; the recurrence over time stays serial, exactly as in
// scipy.signal.sosfilt, which is why the results agree to round-off.
//
// Each section has an explicit structure (iir1 style: the caller chooses):
//
//   tdf2   transposed direct form II, scipy's structure:
//            y = b0 x + s1;  s1' = b1 x - a1 y + s2;  s2' = b2 x - a2 y
//   delta  the same filter in the delta operator d = z - 1 (Middleton-Goodwin,
//          Kauraniemi et al. 1998):
//            y = b0 x + s1;  s1' = s1 + (B1 x + s2) - A1 y;  s2' = s2 + B2 x - A2 y
//          with B1 = 2 b0 + b1, B2 = b0 + b1 + b2, A1 = 2 + a1, A2 = 1 + a1 + a2.
//          For poles near z = 1 (slow corners at kHz rates, the normal case for
//          PVDF circuits) A1, A2 are small numbers that float32 represents to full
//          relative precision, where a1 ~ -2 and a2 ~ 1 lose the pole position;
//          and the states integrate small increments instead of cancelling large
//          terms. The delta state maps linearly onto the tdf2 state:
//            s1_d = s1_t,  s2_d = s1_t + s2_t
//          so zi in and out always use scipy's tdf2 layout.
//
// Real-time contract: sizes are fixed at construction, which is the only place
// that allocates or throws. step() and process() allocate nothing, throw nothing,
// and run with flush-to-zero enabled (restored on return). A non-finite input
// sample never reaches the state: process() restores the state it had before the
// call and reports the first bad sample; step() rejects the sample, counts it and
// holds its previous output.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "simd.hpp"

namespace tactile {

enum class SectionForm : std::uint8_t { tdf2 = 0, delta = 1 };

template <typename T>
class SosCascade {
public:
    using V = simd::vec<T>;
    static constexpr std::size_t W = simd::Vec<T, 32>::lanes;
    // Channels are processed in tiles of at most this many vectors so that a
    // chunk of samples for one tile stays in L1 cache.
    static constexpr std::size_t kTileVecs = 8;
    static constexpr std::size_t kBufBytes = 16384;

    // sos: n_sections rows of (b0, b1, b2, a0, a1, a2) in double precision; each
    // row is normalised by its a0 (which must be non-zero). forms: one SectionForm
    // per section, or nullptr for all tdf2. Coefficients of a delta section are
    // derived in double precision before rounding to T.
    SosCascade(const double* sos, std::size_t n_sections, std::size_t channels,
               const SectionForm* forms = nullptr)
        : n_sections_(n_sections), channels_(channels) {
        if (n_sections == 0) throw std::invalid_argument("sos must have at least one section");
        if (channels == 0) throw std::invalid_argument("channels must be >= 1");
        nvec_ = (channels + W - 1) / W;
        cpad_ = nvec_ * W;
        tile_vecs_ = std::min<std::size_t>(nvec_, kTileVecs);
        chunk_ = std::clamp<std::size_t>(kBufBytes / (tile_vecs_ * sizeof(V)), 16, 512);
        forms_.assign(n_sections, SectionForm::tdf2);
        coef_.resize(n_sections * 5);
        for (std::size_t s = 0; s < n_sections; ++s) {
            const double* r = sos + 6 * s;
            double a0 = r[3];
            if (!(a0 != 0.0) || !std::isfinite(a0))
                throw std::invalid_argument("sos[:, 3] (a0) must be finite and non-zero");
            double b0 = r[0] / a0, b1 = r[1] / a0, b2 = r[2] / a0, a1 = r[4] / a0, a2 = r[5] / a0;
            SectionForm f = forms ? forms[s] : SectionForm::tdf2;
            forms_[s] = f;
            double c[5];
            if (f == SectionForm::delta) {
                c[0] = b0;
                c[1] = 2.0 * b0 + b1;
                c[2] = (b0 + b1) + b2;
                c[3] = 2.0 + a1;
                c[4] = (1.0 + a1) + a2;
            } else {
                c[0] = b0; c[1] = b1; c[2] = b2; c[3] = a1; c[4] = a2;
            }
            for (int j = 0; j < 5; ++j) {
                if (!std::isfinite(c[j])) throw std::invalid_argument("sos coefficients must be finite");
                coef_[5 * s + j] = simd::splat<T>(static_cast<T>(c[j]));
            }
        }
        state_.resize(n_sections * 2 * cpad_);
        snapshot_.resize(n_sections * 2 * cpad_);
        buf_.resize(chunk_ * tile_vecs_ * W);
        last_y_.resize(cpad_);
        isa_ = simd::detect_isa();
    }

    std::size_t channels() const noexcept { return channels_; }
    std::size_t sections() const noexcept { return n_sections_; }
    SectionForm form(std::size_t s) const noexcept { return forms_[s]; }
    simd::Isa isa() const noexcept { return isa_; }
    // Run the portable baseline kernels instead of the dispatched ones (for
    // testing both paths on one machine). Returns false if `isa` cannot run here.
    bool set_isa(simd::Isa isa) noexcept {
        if (simd::isa_supported(isa)) {
            isa_ = isa;
            return true;
        }
        return false;
    }
    std::uint64_t rejected() const noexcept { return rejected_; }
    // The raw state (internal layout, raw_state_size() values) for a caller's own
    // undo of a tick: copy it out before step(), load it back to undo the step.
    std::size_t raw_state_size() const noexcept { return state_.size(); }
    const T* raw_state() const noexcept { return state_.data(); }
    void load_raw_state(const T* s) noexcept { std::copy(s, s + state_.size(), state_.data()); }
    // The output step() holds for a rejected sample (channels() values): a block call
    // moves it too, so an undo of a whole process() call restores it with the raw state.
    const T* held_output() const noexcept { return last_y_.data(); }
    void load_held_output(const T* y) noexcept { std::copy(y, y + channels_, last_y_.data()); }

    // Filter n samples. x[c * xs_c + t * xs_t] and y[c * ys_c + t * ys_t] with
    // strides in elements; x and y may be the same memory (in-place). Returns true
    // on success; false if a sample is not finite: then *bad_t, *bad_c give the
    // earliest such sample (by time, then channel), y is unspecified and the state
    // is what it was before the call.
    bool process(const T* x, std::ptrdiff_t xs_c, std::ptrdiff_t xs_t, T* y, std::ptrdiff_t ys_c,
                 std::ptrdiff_t ys_t, std::size_t n, std::size_t* bad_t, std::size_t* bad_c) noexcept {
        if (n == 0) return true;
        std::copy(state_.data(), state_.data() + state_.size(), snapshot_.data());
        DenormalGuard guard;
        bool ok;
#if TM_HAVE_DISPATCH
        if (isa_ == simd::Isa::avx2_fma)
            ok = process_avx2(x, xs_c, xs_t, y, ys_c, ys_t, n, bad_t, bad_c);
        else
#endif
            ok = process_base(x, xs_c, xs_t, y, ys_c, ys_t, n, bad_t, bad_c);
        if (!ok) {
            std::copy(snapshot_.data(), snapshot_.data() + state_.size(), state_.data());
            return false;
        }
        for (std::size_t c = 0; c < channels_; ++c) last_y_[c] = y[c * ys_c + (n - 1) * ys_t];
        return true;
    }

    // One sample per channel: x[channels] -> y[channels] (contiguous). A sample
    // with any non-finite channel is rejected as a whole: counted, the state kept,
    // and y set to the previous output. Returns false when rejected.
    bool step(const T* x, T* y) noexcept {
        bool ok = true;
        for (std::size_t c = 0; c < channels_; ++c) ok &= is_finite(x[c]);
        if (!ok) {
            ++rejected_;
            for (std::size_t k = 0; k < channels_; ++k) y[k] = last_y_[k];
            return false;
        }
        DenormalGuard guard;
#if TM_HAVE_DISPATCH
        if (isa_ == simd::Isa::avx2_fma)
            step_avx2(x, y);
        else
#endif
            step_base(x, y);
        return true;
    }

    // State in scipy's layout: zi[(s * channels + c) * 2 + j], j = 0, 1 (tdf2 s1, s2).
    void get_state(T* zi) const noexcept {
        for (std::size_t s = 0; s < n_sections_; ++s)
            for (std::size_t c = 0; c < channels_; ++c) {
                T s1 = state_[(2 * s) * cpad_ + c], s2 = state_[(2 * s + 1) * cpad_ + c];
                if (forms_[s] == SectionForm::delta) s2 = s2 - s1;
                zi[(s * channels_ + c) * 2 + 0] = s1;
                zi[(s * channels_ + c) * 2 + 1] = s2;
            }
    }
    void set_state(const T* zi) noexcept {
        for (std::size_t s = 0; s < n_sections_; ++s)
            for (std::size_t c = 0; c < channels_; ++c) {
                T s1 = zi[(s * channels_ + c) * 2 + 0], s2 = zi[(s * channels_ + c) * 2 + 1];
                if (forms_[s] == SectionForm::delta) s2 = s1 + s2;
                state_[(2 * s) * cpad_ + c] = s1;
                state_[(2 * s + 1) * cpad_ + c] = s2;
            }
        // The held output for rejected samples is undefined after a state change:
        // it becomes the response of the new state to a zero input.
        for (std::size_t c = 0; c < channels_; ++c) last_y_[c] = state_[c];
    }
    void reset() noexcept {
        std::fill(state_.data(), state_.data() + state_.size(), T(0));
        std::fill(last_y_.data(), last_y_.data() + last_y_.size(), T(0));
        rejected_ = 0;
    }

private:
    // ---- the per-section recurrence
    // Written so that only y -> s1 -> y (two fused multiply-adds) is serial from
    // one sample to the next; the products of x and the s2 terms are off that path.
    template <bool Delta>
    static TM_ALWAYS_INLINE V biquad(V x, V& s1, V& s2, const V* c) {
        V y = c[0] * x + s1;
        if (Delta) {
            V u = s1 + (c[1] * x + s2);
            s2 = (s2 + c[2] * x) - c[4] * y;
            s1 = u - c[3] * y;
        } else {
            s1 = (c[1] * x + s2) - c[3] * y;
            s2 = c[2] * x - c[4] * y;
        }
        return y;
    }

    // One section over K samples of G channel vectors, states held in registers
    // (the loops over g are fully unrolled).
    template <int G, bool Delta>
    static TM_ALWAYS_INLINE void run_section(V* buf, std::size_t row, std::size_t K, const V* c,
                                             V* s1p, V* s2p) {
        V s1[G], s2[G];
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) {
            s1[g] = s1p[g];
            s2[g] = s2p[g];
        }
        for (std::size_t k = 0; k < K; ++k) {
            V* r = buf + k * row;
#pragma GCC unroll 8
            for (int g = 0; g < G; ++g) r[g] = biquad<Delta>(r[g], s1[g], s2[g], c);
        }
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) {
            s1p[g] = s1[g];
            s2p[g] = s2[g];
        }
    }

    // Two consecutive sections in one pass, the second one sample behind the
    // first: twice the independent chains in flight, so the FMA latency that
    // bounds a single section is hidden.
    template <int G, bool D1, bool D2>
    static TM_ALWAYS_INLINE void run_section_pair(V* buf, std::size_t row, std::size_t K, const V* ca,
                                                  V* s1a_p, V* s2a_p, const V* cb, V* s1b_p, V* s2b_p) {
        V s1a[G], s2a[G], s1b[G], s2b[G];
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) {
            s1a[g] = s1a_p[g]; s2a[g] = s2a_p[g];
            s1b[g] = s1b_p[g]; s2b[g] = s2b_p[g];
        }
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) buf[g] = biquad<D1>(buf[g], s1a[g], s2a[g], ca);
        for (std::size_t k = 1; k < K; ++k) {
            V* r = buf + k * row;
            V* q = r - row;
#pragma GCC unroll 8
            for (int g = 0; g < G; ++g) {
                r[g] = biquad<D1>(r[g], s1a[g], s2a[g], ca);
                q[g] = biquad<D2>(q[g], s1b[g], s2b[g], cb);
            }
        }
        V* q = buf + (K - 1) * row;
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) q[g] = biquad<D2>(q[g], s1b[g], s2b[g], cb);
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) {
            s1a_p[g] = s1a[g]; s2a_p[g] = s2a[g];
            s1b_p[g] = s1b[g]; s2b_p[g] = s2b[g];
        }
    }

    template <bool D1, bool D2>
    static TM_ALWAYS_INLINE void run_pair_groups(V* buf, std::size_t tv, std::size_t K, const V* ca, V* s1a,
                                                 V* s2a, const V* cb, V* s1b, V* s2b) {
        // Groups of two vectors: 4 chains, 8 states and 10 coefficients fit the
        // 16 vector registers (groups of three spilled and ran slower).
        std::size_t v = 0;
        for (; v + 2 <= tv; v += 2)
            run_section_pair<2, D1, D2>(buf + v, tv, K, ca, s1a + v, s2a + v, cb, s1b + v, s2b + v);
        if (v < tv) run_section_pair<1, D1, D2>(buf + v, tv, K, ca, s1a + v, s2a + v, cb, s1b + v, s2b + v);
    }

    // All sections over one chunk of a tile: in pairs where possible.
    TM_ALWAYS_INLINE void run_cascade(V* vbuf, std::size_t tv, std::size_t K, std::size_t v0) noexcept {
        V* vstate = reinterpret_cast<V*>(state_.data());
        const V* vcoef = coef_.data();
        std::size_t s = 0;
        if (K > 1) {
            for (; s + 2 <= n_sections_; s += 2) {
                const V* ca = vcoef + 5 * s;
                const V* cb = ca + 5;
                V* s1a = vstate + (2 * s) * nvec_ + v0;
                V* s2a = s1a + nvec_;
                V* s1b = s2a + nvec_;
                V* s2b = s1b + nvec_;
                const int code = int(forms_[s] == SectionForm::delta) * 2 + int(forms_[s + 1] == SectionForm::delta);
                switch (code) {
                    case 0: run_pair_groups<false, false>(vbuf, tv, K, ca, s1a, s2a, cb, s1b, s2b); break;
                    case 1: run_pair_groups<false, true>(vbuf, tv, K, ca, s1a, s2a, cb, s1b, s2b); break;
                    case 2: run_pair_groups<true, false>(vbuf, tv, K, ca, s1a, s2a, cb, s1b, s2b); break;
                    default: run_pair_groups<true, true>(vbuf, tv, K, ca, s1a, s2a, cb, s1b, s2b); break;
                }
            }
        }
        for (; s < n_sections_; ++s) {
            V* s1p = vstate + (2 * s) * nvec_ + v0;
            V* s2p = s1p + nvec_;
            if (forms_[s] == SectionForm::delta)
                run_section_groups<true>(vbuf, tv, K, vcoef + 5 * s, s1p, s2p);
            else
                run_section_groups<false>(vbuf, tv, K, vcoef + 5 * s, s1p, s2p);
        }
    }

    template <bool Delta>
    TM_ALWAYS_INLINE void run_section_groups(V* buf, std::size_t tv, std::size_t K, const V* c, V* s1p,
                                             V* s2p) const {
        std::size_t v = 0;
        for (; v + 4 <= tv; v += 4) run_section<4, Delta>(buf + v, tv, K, c, s1p + v, s2p + v);
        switch (tv - v) {
            case 3: run_section<3, Delta>(buf + v, tv, K, c, s1p + v, s2p + v); break;
            case 2: run_section<2, Delta>(buf + v, tv, K, c, s1p + v, s2p + v); break;
            case 1: run_section<1, Delta>(buf + v, tv, K, c, s1p + v, s2p + v); break;
            default: break;
        }
    }

    TM_ALWAYS_INLINE bool process_impl(const T* x, std::ptrdiff_t xs_c, std::ptrdiff_t xs_t, T* y,
                                       std::ptrdiff_t ys_c, std::ptrdiff_t ys_t, std::size_t n,
                                       std::size_t* bad_t, std::size_t* bad_c) noexcept {
        T* buf = buf_.data();
        V* vbuf = reinterpret_cast<V*>(buf);
        for (std::size_t v0 = 0; v0 < nvec_; v0 += tile_vecs_) {
            const std::size_t tv = std::min(tile_vecs_, nvec_ - v0);
            const std::size_t c0 = v0 * W;
            const std::size_t cn = std::min(channels_, c0 + tv * W) - c0;  // real channels in tile
            const std::size_t row = tv * W;                               // scalars per buffer row
            if (cn < row) {  // padding lanes carry zeros through the cascade
                for (std::size_t i = 0; i < chunk_ * row; ++i) buf[i] = T(0);
            }
            for (std::size_t t0 = 0; t0 < n; t0 += chunk_) {
                const std::size_t K = std::min(chunk_, n - t0);
                // gather: (channel, time) with any strides -> buf[time][channel]
                bool ok = gather(x, xs_c, xs_t, c0, cn, t0, K, buf, row);
                if (!ok) {
                    locate_bad(x, xs_c, xs_t, c0, cn, t0, K, bad_t, bad_c);
                    return false;
                }
                run_cascade(vbuf, tv, K, v0);
                scatter(buf, row, c0, cn, t0, K, y, ys_c, ys_t);
            }
        }
        return true;
    }

    // Copy a chunk of samples into the time-major buffer and check them. Where
    // time is the contiguous axis, W x W blocks are transposed in registers (4
    // loads + 8 shuffles per 16 doubles instead of 16 scalar moves).
    static TM_ALWAYS_INLINE bool gather(const T* x, std::ptrdiff_t xs_c, std::ptrdiff_t xs_t, std::size_t c0,
                                        std::size_t cn, std::size_t t0, std::size_t K, T* buf,
                                        std::size_t row) {
        bool ok = true;
        std::size_t c_done = 0;
        if (xs_t == 1) {
            const std::size_t tv = row / W;
            V* vbuf = reinterpret_cast<V*>(buf);
            V acc = simd::splat<T>(T(0));
            const V zero = simd::splat<T>(T(0));
            const std::size_t groups = (cn + W - 1) / W;
            for (std::size_t g = 0; g < groups; ++g) {
                const T* base = x + (c0 + g * W) * xs_c + t0;
                const std::size_t rows = std::min<std::size_t>(W, cn - g * W);  // a partial group reads zeros
                std::size_t k = 0;
                for (; k + W <= K; k += W) {
                    V r[W];
#pragma GCC unroll 8
                    for (std::size_t i = 0; i < W; ++i) {
                        r[i] = i < rows ? simd::load<V>(base + i * xs_c + k) : zero;
                        acc = acc + r[i] * zero;  // NaN once any value is NaN or Inf
                    }
                    simd::transpose(r);
#pragma GCC unroll 8
                    for (std::size_t j = 0; j < W; ++j) vbuf[(k + j) * tv + g] = r[j];
                }
                for (; k < K; ++k)
                    for (std::size_t i = 0; i < rows; ++i) {
                        T v = base[i * xs_c + k];
                        ok &= is_finite(v);
                        buf[k * row + g * W + i] = v;
                    }
            }
            for (std::size_t i = 0; i < W; ++i) ok &= is_finite(acc[i]);
            c_done = cn;
        }
        for (std::size_t c = c_done; c < cn; ++c) {
            const T* xp = x + (c0 + c) * xs_c + t0 * xs_t;
            for (std::size_t k = 0; k < K; ++k) {
                T v = xp[k * xs_t];
                ok &= is_finite(v);
                buf[k * row + c] = v;
            }
        }
        return ok;
    }

    static TM_ALWAYS_INLINE void scatter(const T* buf, std::size_t row, std::size_t c0, std::size_t cn,
                                         std::size_t t0, std::size_t K, T* y, std::ptrdiff_t ys_c,
                                         std::ptrdiff_t ys_t) {
        std::size_t c_done = 0;
        if (ys_t == 1) {
            const std::size_t tv = row / W;
            const V* vbuf = reinterpret_cast<const V*>(buf);
            const std::size_t groups = (cn + W - 1) / W;
            for (std::size_t g = 0; g < groups; ++g) {
                T* base = y + (c0 + g * W) * ys_c + t0;
                const std::size_t rows = std::min<std::size_t>(W, cn - g * W);
                std::size_t k = 0;
                for (; k + W <= K; k += W) {
                    V r[W];
#pragma GCC unroll 8
                    for (std::size_t j = 0; j < W; ++j) r[j] = vbuf[(k + j) * tv + g];
                    simd::transpose(r);
#pragma GCC unroll 8
                    for (std::size_t i = 0; i < W; ++i)
                        if (i < rows) simd::store(base + i * ys_c + k, r[i]);
                }
                for (; k < K; ++k)
                    for (std::size_t i = 0; i < rows; ++i) base[i * ys_c + k] = buf[k * row + g * W + i];
            }
            c_done = cn;
        }
        for (std::size_t c = c_done; c < cn; ++c) {
            T* yp = y + (c0 + c) * ys_c + t0 * ys_t;
            for (std::size_t k = 0; k < K; ++k) yp[k * ys_t] = buf[k * row + c];
        }
    }

    // The first non-finite sample: earliest in time within the chunk where the
    // tile check failed; channels of later tiles are scanned up to that time
    // (earlier tiles were clean over the whole signal).
    void locate_bad(const T* x, std::ptrdiff_t xs_c, std::ptrdiff_t xs_t, std::size_t c0, std::size_t cn,
                    std::size_t t0, std::size_t K, std::size_t* bad_t, std::size_t* bad_c) const noexcept {
        std::size_t bt = t0 + K, bc = 0;
        for (std::size_t k = 0; k < K && bt == t0 + K; ++k)
            for (std::size_t c = 0; c < cn; ++c)
                if (!is_finite(x[(c0 + c) * xs_c + (t0 + k) * xs_t])) {
                    bt = t0 + k;
                    bc = c0 + c;
                    break;
                }
        for (std::size_t t = 0; t < bt; ++t)
            for (std::size_t c = c0 + cn; c < channels_; ++c)
                if (!is_finite(x[c * xs_c + t * xs_t])) {
                    *bad_t = t;
                    *bad_c = c;
                    return;
                }
        *bad_t = bt;
        *bad_c = bc;
    }

    // Channels [v*W, v*W + W) of a sample as a vector, zeros past the last
    // channel. Loaded straight from x: writing scalars to a buffer and reading it
    // back as a vector would stall on store forwarding.
    TM_ALWAYS_INLINE V load_sample(const T* x, std::size_t v) const noexcept {
        const std::size_t c = v * W;
        if (c + W <= channels_) return simd::load<V>(x + c);
        return simd::load_partial(x + c, channels_ - c);
    }
    TM_ALWAYS_INLINE void store_sample(T* y, std::size_t v, V r) const noexcept {
        const std::size_t c = v * W;
        if (c + W <= channels_) {
            simd::store(y + c, r);
        } else {
            for (std::size_t i = 0; c + i < channels_; ++i) y[c + i] = r[i];
        }
    }

    // One sample: each group of channel vectors goes through all sections in
    // registers (only the states touch memory), with the same biquad() as
    // process(), so any chunking of a signal, down to single samples, gives
    // identical output.
    template <int G>
    TM_ALWAYS_INLINE void step_group(const T* in, T* out, std::size_t v0) noexcept {
        V x[G];
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) x[g] = load_sample(in, v0 + g);
        V* vstate = reinterpret_cast<V*>(state_.data());
        for (std::size_t s = 0; s < n_sections_; ++s) {
            const V* c = coef_.data() + 5 * s;
            V* s1 = vstate + (2 * s) * nvec_ + v0;
            V* s2 = s1 + nvec_;
            if (forms_[s] == SectionForm::delta) {
#pragma GCC unroll 8
                for (int g = 0; g < G; ++g) x[g] = biquad<true>(x[g], s1[g], s2[g], c);
            } else {
#pragma GCC unroll 8
                for (int g = 0; g < G; ++g) x[g] = biquad<false>(x[g], s1[g], s2[g], c);
            }
        }
        V* held = reinterpret_cast<V*>(last_y_.data());
#pragma GCC unroll 8
        for (int g = 0; g < G; ++g) {
            held[v0 + g] = x[g];
            store_sample(out, v0 + g, x[g]);
        }
    }

    TM_ALWAYS_INLINE void step_impl(const T* x, T* y) noexcept {
        std::size_t v = 0;
        for (; v + 4 <= nvec_; v += 4) step_group<4>(x, y, v);
        switch (nvec_ - v) {
            case 3: step_group<3>(x, y, v); break;
            case 2: step_group<2>(x, y, v); break;
            case 1: step_group<1>(x, y, v); break;
            default: break;
        }
    }

    bool process_base(const T* x, std::ptrdiff_t xs_c, std::ptrdiff_t xs_t, T* y, std::ptrdiff_t ys_c,
                      std::ptrdiff_t ys_t, std::size_t n, std::size_t* bt, std::size_t* bc) noexcept {
        return process_impl(x, xs_c, xs_t, y, ys_c, ys_t, n, bt, bc);
    }
    void step_base(const T* x, T* y) noexcept { step_impl(x, y); }
#if TM_HAVE_DISPATCH
    TM_TARGET_AVX2 bool process_avx2(const T* x, std::ptrdiff_t xs_c, std::ptrdiff_t xs_t, T* y,
                                     std::ptrdiff_t ys_c, std::ptrdiff_t ys_t, std::size_t n,
                                     std::size_t* bt, std::size_t* bc) noexcept {
        return process_impl(x, xs_c, xs_t, y, ys_c, ys_t, n, bt, bc);
    }
    TM_TARGET_AVX2 void step_avx2(const T* x, T* y) noexcept { step_impl(x, y); }
#endif

    std::size_t n_sections_, channels_;
    std::size_t nvec_ = 0, cpad_ = 0, tile_vecs_ = 0, chunk_ = 0;
    std::vector<SectionForm> forms_;
    AlignedBuffer<V> coef_;      // n_sections x 5 splatted coefficients
    AlignedBuffer<T> state_;     // [section][s1|s2][cpad]
    AlignedBuffer<T> snapshot_;  // state before the running process() call
    AlignedBuffer<T> buf_;       // chunk x tile of samples, time-major
    AlignedBuffer<T> last_y_;    // held output for rejected samples
    std::uint64_t rejected_ = 0;
    simd::Isa isa_ = simd::Isa::baseline;
};

}  // namespace tactile
