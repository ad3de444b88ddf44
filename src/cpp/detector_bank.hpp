// detector_bank.hpp - the filter-bank slip detector: a bank of first-order IIR
// filters over the stress rates in front of the Jordan MLP kernel (jordan_mlp.hpp).
//
// The paper's net reads [v_L, v_R, u_L, u_R] per ridge and remembers only its own
// y_pred; a slip that creeps in differs from a stop in the recent history of the
// rates. This stage keeps that history in a few filter states (python:
// tactile_mirror.detector.bank, the specification), per ridge and tick, with
// d = v_L - v_R, s = v_L + v_R and a(tau) = exp(-1 / (fs tau)):
//
//     for tau in lp_taus:  lpd = a lpd + (1 - a) d,  lps = a lps + (1 - a) s   (Pa/s)
//     for tau in abs_taus: lpa = a lpa + (1 - a) |d|                          (Pa/s)
//     load  = b load  + d / fs,  press = b press + s / fs,  b = a(load_tau)   (Pa)
//     peak  = max(|load|, c peak),                           c = a(peak_tau)  (Pa)
//
// and runs the Jordan net on [v_L, v_R, u_L, u_R, lpd_1, lps_1, ..., lpa_1, ...,
// load, press, peak]. Ridges are independent, unless the bank has the pad's mean: then
// the net also reads, after a ridge's own features, their mean over the pad's ridges
// (summed in ridge order, then divided by their count, as the python), the same for
// every ridge (a stop stills every ridge at once, a creeping slip reaches them one
// after another). With knees (one per input), every input x is then compressed to
// sign(x) log(1 + |x| / knee) (simd::log_compress, bit for bit the python's
// detector.bank.log_compress): the features are heavy-tailed.
//
// RTNeural-like: sizes fixed at construction (which may throw); step(), run(), the
// state accessors allocate nothing and throw nothing. Block runs go in chunks of the
// net's chunk_ticks(): the features are computed with the ridges in SIMD lanes and
// written time-contiguous straight into the net's staging rows, which its block path
// normalises in place and runs (JordanMLP::run_staged); the same pass tells whether
// every input was finite (run()'s result). step() and run() give the same bits.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <stdexcept>
#include <type_traits>

#include "jordan_mlp.hpp"

namespace tactile {
namespace detector {

template <typename T>
class BankJordan {
public:
    static constexpr int n_raw = 4;
    static constexpr int kMaxTaus = 8;
    static constexpr int n_outputs = 3;
    static constexpr int kMaxFeatures = n_raw + 3 * kMaxTaus + 3;
    static constexpr int kMaxInputs = 2 * kMaxFeatures;

    /// Features of a ridge: 4 + 2 n_lp + n_abs + 3.
    static int feature_count(int n_lp, int n_abs) noexcept { return n_raw + 2 * n_lp + n_abs + 3; }
    /// The net's inputs: the features, and as many again with the pad's mean. Weights
    /// as JordanMLP with that many inputs.
    static int input_count(int n_lp, int n_abs, bool pad_mean) noexcept {
        return (pad_mean ? 2 : 1) * feature_count(n_lp, n_abs);
    }

    BankJordan(int n_hidden, int n_ridges, const double* w1, const double* b1, const double* w2, const double* b2,
               const double* input_mean, const double* input_gain, double fs, int n_lp, const double* lp_taus,
               int n_abs, const double* abs_taus, double load_tau, double peak_tau,
               Activation activation = Activation::exact, const double* knee = nullptr, bool pad_mean = false)
        : net_((pad_mean ? 2 : 1) * checked_features(n_lp, n_abs), n_hidden, n_ridges, w1, b1, w2, b2, input_mean,
               input_gain, activation),
          n_r_(n_ridges),
          n_lp_(n_lp),
          n_abs_(n_abs),
          nf_(feature_count(n_lp, n_abs)),
          ni_(input_count(n_lp, n_abs, pad_mean)),
          ns_(2 * n_lp + n_abs + 3),
          pad_mean_(pad_mean) {
        if (!(std::isfinite(fs) && fs > 0)) throw std::invalid_argument("fs must be a positive number of Hz");
        auto leak = [fs](double tau) {
            if (!(std::isfinite(tau) && tau > 0)) throw std::invalid_argument("time constants must be positive s");
            return std::exp(-1.0 / (fs * tau));
        };
        for (int k = 0; k < n_lp; ++k) {
            a_lp_[k] = static_cast<T>(leak(lp_taus[k]));
            g_lp_[k] = static_cast<T>(1.0 - leak(lp_taus[k]));
        }
        for (int k = 0; k < n_abs; ++k) {
            a_abs_[k] = static_cast<T>(leak(abs_taus[k]));
            g_abs_[k] = static_cast<T>(1.0 - leak(abs_taus[k]));
        }
        if (knee) {
            for (int j = 0; j < ni_; ++j) {
                if (!(std::isfinite(knee[j]) && knee[j] > 0)) throw std::invalid_argument("knee must be positive finite numbers (one per input)");
                ik_[j] = static_cast<T>(1.0 / knee[j]);  // as the python: 1 / knee in double, then T
                if (!(std::isfinite(ik_[j]) && ik_[j] > 0))  // 0 * inf would make a NaN of a zero input
                    throw std::invalid_argument("knee must lie in [1e-30, 1e30] (its reciprocal a normal float)");
            }
            compress_ = true;
        }
        // The pad's mean is the same for every ridge: its share of the net's input
        // projection is computed once per tick (JordanMLP::set_shared_inputs).
        if (pad_mean) net_.set_shared_inputs(nf_);
        b_ = static_cast<T>(leak(load_tau));
        c_ = static_cast<T>(leak(peak_tau));
        inv_fs_ = static_cast<T>(1.0 / fs);
        // Ridge stride of the lane-major state and the step's feature-major features:
        // the net's (JordanMLP::step_feature_major), whole vectors of the widest path
        // with room for its ghost instances.
        rs_ = std::size_t(net_.feature_major_stride());
        // (+ nf_ rows of raw features for a compressed bank with the pad's mean)
        const std::size_t n_raw_rows = pad_mean && compress_ ? std::size_t(nf_) : 0;
        const std::size_t count = rs_ * (std::size_t(ns_) + std::size_t(ni_) + n_raw_rows) + 16;
        void* mem = std::aligned_alloc(64, ((count * sizeof(T) + 63) / 64) * 64);
        if (!mem) throw std::bad_alloc();
        buf_.reset(mem);
        std::memset(mem, 0, count * sizeof(T));
        T* p = static_cast<T*>(mem);
        st_ = p;
        p += rs_ * ns_;
        feat_ = p;
        p += rs_ * std::size_t(ni_);
        raw_ = n_raw_rows ? p : nullptr;
    }

    int n_hidden() const noexcept { return net_.n_hidden(); }
    int n_ridges() const noexcept { return n_r_; }
    int n_features() const noexcept { return nf_; }
    /// The net's inputs: n_features(), twice that with the pad's mean.
    int n_inputs() const noexcept { return ni_; }
    /// Whether the net also reads the pad's mean of the features.
    bool pad_mean() const noexcept { return pad_mean_; }
    /// Filter states per ridge (2 n_lp + n_abs + 3).
    int n_state() const noexcept { return ns_; }
    /// Whether the features are compressed (knees given).
    bool compressed() const noexcept { return compress_; }
    JordanMLP<T>& net() noexcept { return net_; }
    const JordanMLP<T>& net() const noexcept { return net_; }

    /// State: y_pred(t-1) per ridge (n_ridges) and the filter states (n_ridges, n_state) row-major,
    /// in feature order after the four rates.
    void get_state(T* y_pred, T* filt) const noexcept {
        net_.get_state(y_pred);
        for (int r = 0; r < n_r_; ++r)
            for (int j = 0; j < ns_; ++j) filt[std::size_t(r) * ns_ + j] = st_[j * rs_ + r];
    }
    void set_state(const T* y_pred, const T* filt) noexcept {
        net_.set_state(y_pred);
        for (int r = 0; r < n_r_; ++r)
            for (int j = 0; j < ns_; ++j) st_[j * rs_ + r] = filt[std::size_t(r) * ns_ + j];
    }
    /// The filter states as stored (the pipeline's overflow guard reads, checks and
    /// restores them whole): lane-major, state j of ridge r at [j * stride + r], the
    /// lanes from n_ridges on zero. get_state() gives them per ridge.
    const T* filter_state() const noexcept { return st_; }
    std::size_t filter_state_size() const noexcept { return rs_ * ns_; }
    void load_filter_state(const T* filt) noexcept {
        for (std::size_t k = 0; k < rs_ * ns_; ++k) st_[k] = filt[k];
    }
    void reset() noexcept {
        net_.reset();
        for (std::size_t k = 0; k < rs_ * ns_; ++k) st_[k] = T(0);
    }

    /// One tick. in: (n_ridges, 4) row-major [v_L, v_R, u_L, u_R]; out: (n_ridges, 3) row-major.
    /// The features are computed a vector of ridges at a time into feature-major rows,
    /// which the net normalises in place (JordanMLP::step_feature_major).
    void step(const T* in, T* out) noexcept {
#if TM_HAVE_DISPATCH
        if (net_.isa() == simd::Isa::avx2_fma)
            features_tick_avx2(in);
        else
#endif
            features_tick_base(in);
        net_.step_feature_major(feat_, out);
    }

    /// n ticks: channel i of ridge r at tick t is x[r * sr + i * si + t * st]; outputs
    /// (n_ridges, n) row-major with row stride ld, as JordanMLP::run.
    ///
    /// Returns whether every input value was finite. The check rides on the feature
    /// pass, which reads every value anyway: a separate pass before the run read the
    /// whole block from memory once more (measured, 6 ridges: 10 ns per tick in float,
    /// 25 in double, of 190 and 350). Non-finite inputs run through harmlessly (the
    /// sigmoids clamp NaN) but leave a state and outputs of no meaning: a caller that
    /// must refuse them saves the state before (get_state) and restores it on false.
    bool run(const T* x, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, std::ptrdiff_t n, T* y_slip,
             T* y_non, T* y_pred, std::ptrdiff_t ld) noexcept {
        constexpr int K = JordanMLP<T>::chunk_ticks();
        T bad = 0;  // a sum of x * 0: +-0 while every x is finite, NaN after an Inf or a NaN
        for (std::ptrdiff_t t0 = 0; t0 < n; t0 += K) {
            const int m = int(n - t0 < K ? n - t0 : K);
            bad += features_chunk(x + t0 * st, sr, si, st, m, n - t0);
            net_.run_staged(m, y_slip + t0, y_non + t0, y_pred + t0, ld);
        }
        return bad == T(0);
    }

    /// Mean time of one tick (step()) of all ridges over n_iter ticks, ns (best of repeats),
    /// measured in C++; the state is restored afterwards. NaN for more than 64 ridges.
    double time_step_ns(long n_iter, int repeats = 5) noexcept {
        constexpr int cap = 64;
        if (n_r_ > cap || n_iter < 1) return std::numeric_limits<double>::quiet_NaN();
        T in[4 * cap], out[3 * cap], yp[cap], sv[cap * (2 * kMaxTaus + kMaxTaus + 3)];
        get_state(yp, sv);
        for (int k = 0; k < 4 * n_r_; ++k) in[k] = T(1e3) * T((k % 7) - 3);
        const double best = best_time_ns(n_iter, repeats, [&](long) { step(in, out); });
        set_state(yp, sv);
        return best;
    }

private:
    static int checked_features(int n_lp, int n_abs) {
        if (n_lp < 1 || n_lp > kMaxTaus) throw std::invalid_argument("lp_taus must hold 1 to 8 time constants");
        if (n_abs < 0 || n_abs > kMaxTaus) throw std::invalid_argument("abs_taus must hold 0 to 8 time constants");
        return feature_count(n_lp, n_abs);
    }

    // One tick of one ridge: raw channel i at x[i * si]; updates its filter states z and
    // writes the ridge's features to o[j * ocol]. The scalar definition of the bank's
    // recurrences (detector.bank, the specification); the vector passes below
    // (features_tick, features_chunk_lanes) do the same arithmetic lane by lane.
    __attribute__((always_inline)) inline void ridge_tick(const T* x, std::ptrdiff_t si, T* __restrict z,
                                                          T* __restrict o, std::ptrdiff_t ocol) const noexcept {
        const T vl = x[0], vr = x[si], ul = x[2 * si], ur = x[3 * si];
        const T d = vl - vr, s = vl + vr, ad = std::fabs(d);
        o[0] = vl;
        o[ocol] = vr;
        o[2 * ocol] = ul;
        o[3 * ocol] = ur;
        int j = 0;
        for (int k = 0; k < n_lp_; ++k, j += 2) {
            z[j] = a_lp_[k] * z[j] + g_lp_[k] * d;
            z[j + 1] = a_lp_[k] * z[j + 1] + g_lp_[k] * s;
        }
        for (int k = 0; k < n_abs_; ++k, ++j) z[j] = a_abs_[k] * z[j] + g_abs_[k] * ad;
        z[j] = b_ * z[j] + d * inv_fs_;
        z[j + 1] = b_ * z[j + 1] + s * inv_fs_;
        const T held = c_ * z[j + 2], now = std::fabs(z[j]);
        z[j + 2] = now > held ? now : held;
        for (int k = 0; k < ns_; ++k) o[(4 + k) * ocol] = z[k];
    }

    // m <= K ticks of inputs into the net's staging rows, (n_ridges, ni, K), time
    // contiguous (the features, then the pad's mean; compressed with knees); returns the sum of every input value times 0 (see run()).
    // avail: ticks of input from x0 on (the next chunk's are prefetched, never beyond).
    T features_chunk(const T* x0, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, int m,
                     std::ptrdiff_t avail) noexcept {
        constexpr int K = JordanMLP<T>::chunk_ticks();
        const T bad = features_chunk_raw(x0, sr, si, st, m, avail);
        if (pad_mean_) pad_mean_rows(net_.staging(), K, std::ptrdiff_t(ni_) * K, m);
        if (compress_) {
#if TM_HAVE_DISPATCH
            if (net_.isa() == simd::Isa::avx2_fma)
                compress_staging_avx2(m);
            else
#endif
                compress_rows<simd::kBaseBytes>(net_.staging(), K, n_r_ * ni_, m);
        }
        return bad;
    }
    T features_chunk_raw(const T* x0, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, int m,
                         std::ptrdiff_t avail) noexcept {
        if (st != 1) return features_chunk_scalar(x0, sr, si, st, 0, m);
#if TM_HAVE_DISPATCH
        if (net_.isa() == simd::Isa::avx2_fma) return features_chunk_avx2(x0, sr, si, m, avail);
#endif
        if (n_lp_ == 4 && n_abs_ == 2) return features_chunk_lanes<simd::kBaseBytes, 4, 2>(x0, sr, si, m, avail);
        return features_chunk_lanes<simd::kBaseBytes, -1, -1>(x0, sr, si, m, avail);
    }

    // The pad's mean rows of a chunk's staging rows (feature i of ridge r at
    // p[r * rr + i * fr + t], t < n, time contiguous): rows nf_ + i of every ridge get
    // sum_r x_i(r) / n_ridges, summed in ridge order (the python's
    // detector.bank.bank_features; features_tick adds and divides the same way, so
    // step() and run() agree bit for bit).
    // A vector of ticks at a time, n rounded up to whole vectors (within the rows'
    // chunk_ticks(), a multiple of the vector; the values past n are never read).
    void pad_mean_rows(T* p, std::ptrdiff_t fr, std::ptrdiff_t rr, std::ptrdiff_t n) const noexcept {
        typedef typename simd::Vec<T, simd::kBaseBytes>::type V;
        constexpr int NL = simd::Vec<T, simd::kBaseBytes>::lanes;
        static_assert(JordanMLP<T>::chunk_ticks() % NL == 0, "staging rows hold whole vectors");
        const T nr = T(n_r_);
        for (int i = 0; i < nf_; ++i) {
            const T* src = p + i * fr;
            T* dst = p + (nf_ + i) * fr;
            for (std::ptrdiff_t t = 0; t < n; t += NL) {
                V acc = simd::load<V>(src + t);
                for (int r = 1; r < n_r_; ++r) acc += simd::load<V>(src + r * rr + t);
                const V mean = acc / nr;
                for (int r = 0; r < n_r_; ++r) simd::store(dst + r * rr + t, mean);
            }
        }
    }

    // The compression of n_rows rows of inputs, row k at p + k * stride holding
    // input k % ni_ (the staging rows of a chunk: (n_ridges, ni, K)), its first n
    // values rounded up to whole vectors (within the stride, a multiple of the vector).
    // Element-wise, so a run() over a vector of ticks gives the bits of step()'s
    // compression over a vector of ridges (features_tick).
    template <int B>
    __attribute__((always_inline)) inline void compress_rows(T* p, std::ptrdiff_t stride, int n_rows,
                                                             std::ptrdiff_t n) const noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        for (int k = 0, i = 0; k < n_rows; ++k, i = i + 1 == ni_ ? 0 : i + 1) {
            const V ik = V{} + ik_[i];
            T* row = p + k * stride;
            for (std::ptrdiff_t t = 0; t < n; t += NL)
                simd::store(row + t, simd::log_compress<T, B>(simd::load<V>(row + t), ik));
        }
    }
#if TM_HAVE_DISPATCH
    // AVX2 without FMA: the bank's a z + g d must round as ridge_tick's multiplies and
    // add do, so that step() and run() agree bit for bit; a fused multiply-add would not.
    __attribute__((target("avx2"), noinline)) T features_chunk_avx2(const T* x0, std::ptrdiff_t sr,
                                                                     std::ptrdiff_t si, int m, std::ptrdiff_t avail) noexcept {
        if (n_lp_ == 4 && n_abs_ == 2) return features_chunk_lanes<32, 4, 2>(x0, sr, si, m, avail);
        return features_chunk_lanes<32, -1, -1>(x0, sr, si, m, avail);
    }
#endif

    // One tick of the bank for a vector of ridges: z[0 .. n_state) their states,
    // updated from the rates vl, vr: ridge_tick's arithmetic, lane by lane (multiplies
    // and adds, compiled without FMA so that the roundings are the same). NLP, NABS:
    // the filter counts when known at compile time, else -1.
    template <int B, int NLP, int NABS>
    __attribute__((always_inline)) inline void lanes_tick(typename simd::Vec<T, B>::type* z,
                                                          typename simd::Vec<T, B>::type vl,
                                                          typename simd::Vec<T, B>::type vr) const noexcept {
        typedef typename simd::Vec<T, B>::type V;
        typedef typename simd::Vec<T, B>::itype IV;
        typedef typename std::remove_reference<decltype(IV{}[0])>::type IT;
        const IV nosign = IV{} + ~(IT(1) << (8 * sizeof(T) - 1));
        const int nlp = NLP >= 0 ? NLP : n_lp_, nab = NABS >= 0 ? NABS : n_abs_;
        const V d = vl - vr, s = vl + vr, ad = (V)((IV)d & nosign);
        int j = 0;
        _Pragma("GCC unroll 8") for (int i = 0; i < nlp; ++i, j += 2) {
            z[j] = a_lp_[i] * z[j] + g_lp_[i] * d;
            z[j + 1] = a_lp_[i] * z[j + 1] + g_lp_[i] * s;
        }
        _Pragma("GCC unroll 8") for (int i = 0; i < nab; ++i, ++j) z[j] = a_abs_[i] * z[j] + g_abs_[i] * ad;
        z[j] = b_ * z[j] + d * inv_fs_;
        z[j + 1] = b_ * z[j + 1] + s * inv_fs_;
        const V held = c_ * z[j + 2], now = (V)((IV)z[j] & nosign);
        z[j + 2] = now > held ? now : held;
    }

    // The rates of nl (<= lanes) ridges, in: (nl, 4) row-major, to the feature rows
    // f[c * rs + lane], lanes from nl on zero. Transposed in registers: written lane by
    // lane and read back as vectors (lanes_tick's inputs), they stalled on store
    // forwarding.
    template <int B>
    __attribute__((always_inline)) inline void gather_rates(const T* in, int nl, T* f,
                                                            std::ptrdiff_t rs) const noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        static_assert(n_raw == 4, "four rates per ridge");
        if constexpr (NL == 4) {  // one ridge per vector, a 4 x 4 transpose
            V v[4];
            _Pragma("GCC unroll 4") for (int l = 0; l < 4; ++l) v[l] = l < nl ? simd::load<V>(in + 4 * l) : V{};
            simd::transpose(v);
            _Pragma("GCC unroll 4") for (int c = 0; c < 4; ++c) simd::store(f + c * rs, v[c]);
        } else if constexpr (NL == 8) {  // two ridges per vector: [l, l + 4] in 128-bit halves, then 4 x 4 in each
            typedef typename simd::Vec<T, B / 2>::type H;
            H h[8];
            _Pragma("GCC unroll 8") for (int l = 0; l < 8; ++l) h[l] = l < nl ? simd::load<H>(in + 4 * l) : H{};
            V v[4];
            _Pragma("GCC unroll 4") for (int l = 0; l < 4; ++l) v[l] = TM_SHUFFLE(h[l], h[l + 4], 0, 1, 2, 3, 4, 5, 6, 7);
            V t[4];
            t[0] = TM_SHUFFLE(v[0], v[1], 0, 8, 1, 9, 4, 12, 5, 13);
            t[1] = TM_SHUFFLE(v[0], v[1], 2, 10, 3, 11, 6, 14, 7, 15);
            t[2] = TM_SHUFFLE(v[2], v[3], 0, 8, 1, 9, 4, 12, 5, 13);
            t[3] = TM_SHUFFLE(v[2], v[3], 2, 10, 3, 11, 6, 14, 7, 15);
            // lane order now [ridges 0-3 | ridges 4-7] per channel
            simd::store(f + 0 * rs, V(TM_SHUFFLE(t[0], t[2], 0, 1, 8, 9, 4, 5, 12, 13)));
            simd::store(f + 1 * rs, V(TM_SHUFFLE(t[0], t[2], 2, 3, 10, 11, 6, 7, 14, 15)));
            simd::store(f + 2 * rs, V(TM_SHUFFLE(t[1], t[3], 0, 1, 8, 9, 4, 5, 12, 13)));
            simd::store(f + 3 * rs, V(TM_SHUFFLE(t[1], t[3], 2, 3, 10, 11, 6, 7, 14, 15)));
        } else {
            for (int c = 0; c < n_raw; ++c)
                for (int l = 0; l < NL; ++l) f[c * rs + l] = l < nl ? in[l * n_raw + c] : T(0);
        }
    }

    // One tick of inputs for step(): feat_ (ni, rs_) feature-major, every lane of the
    // vectors holding ridges written (the net normalises those in place; the lanes in
    // them past the last ridge get zero rates and states), the pad's means in every lane;
    // the states in st_ updated a vector of ridges at a time.
    void features_tick_base(const T* in) noexcept {
        if (n_lp_ == 4 && n_abs_ == 2) return features_tick<simd::kBaseBytes, 4, 2>(in);
        features_tick<simd::kBaseBytes, -1, -1>(in);
    }
#if TM_HAVE_DISPATCH
    // AVX2 without FMA, as features_chunk_avx2 (log_compress must round as the python's).
    __attribute__((target("avx2"), noinline)) void compress_staging_avx2(int m) noexcept {
        compress_rows<32>(net_.staging(), JordanMLP<T>::chunk_ticks(), n_r_ * ni_, m);
    }
    // AVX2 without FMA, as features_chunk_avx2.
    __attribute__((target("avx2"), noinline)) void features_tick_avx2(const T* in) noexcept {
        if (n_lp_ == 4 && n_abs_ == 2) return features_tick<32, 4, 2>(in);
        features_tick<32, -1, -1>(in);
    }
#endif
    template <int B, int NLP, int NABS>
    __attribute__((always_inline)) inline void features_tick(const T* in) noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr int NSM = NLP >= 0 ? 2 * NLP + NABS + 3 : 2 * kMaxTaus + kMaxTaus + 3;
        const int ns = NLP >= 0 ? NSM : ns_;
        const std::ptrdiff_t rs = std::ptrdiff_t(rs_);
        T* __restrict f = feat_;
        // The vectors holding ridges only: the ghost vectors past them keep whatever finite
        // values they hold (the zeros they were allocated with, or after a switch from a wider
        // SIMD path its last normalised values); the net normalises only the vectors holding
        // instances too, and its groups never read past them.
        for (std::ptrdiff_t r0 = 0; r0 < n_r_; r0 += NL) {
            // The four rates of the vector's ridges, gathered into their feature rows.
            gather_rates<B>(in + r0 * n_raw, n_r_ - r0 < NL ? int(n_r_ - r0) : NL, f + r0, rs);
            V z[NSM] = {};
            _Pragma("GCC unroll 32") for (int j = 0; j < ns; ++j) z[j] = simd::load<V>(st_ + j * rs + r0);
            lanes_tick<B, NLP, NABS>(z, simd::load<V>(f + r0), simd::load<V>(f + rs + r0));
            if (compress_) {
                // compressed as they are stored (the states themselves stay as they are);
                // with the pad's mean, the raw values kept for it in raw_
                T* __restrict raw = raw_;
                _Pragma("GCC unroll 4") for (int c = 0; c < n_raw; ++c) {
                    const V x = simd::load<V>(f + c * rs + r0);
                    if (raw) simd::store(raw + c * rs + r0, x);
                    simd::store(f + c * rs + r0, simd::log_compress<T, B>(x, V{} + ik_[c]));
                }
                _Pragma("GCC unroll 32") for (int j = 0; j < ns; ++j) {
                    simd::store(st_ + j * rs + r0, z[j]);
                    if (raw) simd::store(raw + (n_raw + j) * rs + r0, z[j]);
                    simd::store(f + (n_raw + j) * rs + r0, simd::log_compress<T, B>(z[j], V{} + ik_[n_raw + j]));
                }
            } else {
                _Pragma("GCC unroll 32") for (int j = 0; j < ns; ++j) {
                    simd::store(st_ + j * rs + r0, z[j]);
                    simd::store(f + (n_raw + j) * rs + r0, z[j]);
                }
            }
        }
        if (pad_mean_) {
            // The pad's mean of the raw features, NL features at a time: a tile of NL
            // feature rows x NL ridges transposed in registers holds one ridge's NL
            // features per vector, and the vectors are added in ridge order and divided
            // (pad_mean_rows' additions and division, element by element: the same bits;
            // a scalar sum per feature, stored lane by lane and reloaded as a vector,
            // stalled on store forwarding). The terms are the raw features (raw_ when the
            // ridges' rows were compressed above); the means are compressed element by
            // element as run() compresses its staging rows (the same bits) and written
            // to every lane of their rows (ghosts too: measured, 6 ridges, leaving the
            // ghost vectors as they were made the float step 8 ns slower, not faster).
            const T* src = compress_ ? raw_ : f;  // (f itself without knees: rows < nf_ read, rows >= nf_ written)
            const V nr = V{} + T(n_r_);
            for (int i0 = 0; i0 < nf_; i0 += NL) {
                V acc{};
                for (std::ptrdiff_t r0 = 0; r0 < n_r_; r0 += NL) {
                    V v[NL];
                    _Pragma("GCC unroll 8") for (int k = 0; k < NL; ++k) v[k] =
                        i0 + k < nf_ ? simd::load<V>(src + (i0 + k) * rs + r0) : V{};
                    simd::transpose(v);  // lane k of v[q]: feature i0 + k of ridge r0 + q
                    const int nq = n_r_ - r0 < NL ? int(n_r_ - r0) : NL;
                    acc = r0 == 0 ? v[0] : acc + v[0];
                    for (int q = 1; q < nq; ++q) acc += v[q];
                }
                V m = acc / nr;
                // (the knees as one vector load: lane by lane they stalled on store forwarding;
                // the lanes past the last input read zeros and are never stored)
                if (compress_) m = simd::log_compress<T, B>(m, simd::load<V>(ik_ + nf_ + i0));
                for (int k = 0; k < NL && i0 + k < nf_; ++k) {
                    const V b = V{} + m[k];
                    T* dst = f + (nf_ + i0 + k) * rs;
                    for (std::ptrdiff_t r0 = 0; r0 < rs; r0 += NL) simd::store(dst + r0, b);
                }
            }
        }
    }

    // Ticks t0 .. m - 1 ridge by ridge (scalar ridge_tick), for strided input and the
    // ticks after the last whole vector of them.
    T features_chunk_scalar(const T* x0, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, int t0,
                            int m) noexcept {
        constexpr int K = JordanMLP<T>::chunk_ticks();
        T z[2 * kMaxTaus + kMaxTaus + 3];
        T* out = net_.staging();
        T bad = 0;
        for (int r = 0; r < n_r_; ++r) {
            for (int k = 0; k < ns_; ++k) z[k] = st_[k * rs_ + r];
            T* o = out + std::size_t(r) * ni_ * K;
            const T* xr = x0 + r * sr;
            for (int t = t0; t < m; ++t) {
                const T* xt = xr + t * st;
                bad += ((xt[0] * T(0) + xt[si] * T(0)) + (xt[2 * si] * T(0) + xt[3 * si] * T(0)));
                ridge_tick(xt, si, z, o + t, K);
            }
            for (int k = 0; k < ns_; ++k) st_[k * rs_ + r] = z[k];
        }
        return bad;
    }

    // The feature pass with the ridges in SIMD lanes (time-contiguous input, st = 1).
    // Per vector of NL ridges and NL ticks: the four input rows of each ridge are copied
    // to their staging rows as they are and transposed to one vector of ridges per tick;
    // the bank's recurrences then run on whole vectors (the state of NL ridges in a few
    // registers), and each filter's NL tick vectors are transposed back into NL ridge
    // rows of the staging layout, the net's (the ridge-by-ridge scalar loop took 41 ns
    // per tick of 6 ridges in float, 55 in double, measured). Lanes past the last ridge
    // are ghosts: zero input, zero state, never stored. The arithmetic is ridge_tick's,
    // lane by lane. NLP, NABS: the filter counts when known at compile time (the
    // bundled net's bank, detector.bank.DEFAULT_BANK: 4 low-passes and 2 |d| filters;
    // the states then stay in registers), else -1.
    template <int B, int NLP, int NABS>
    __attribute__((always_inline)) inline T features_chunk_lanes(const T* x0, std::ptrdiff_t sr, std::ptrdiff_t si,
                                                                 int m, std::ptrdiff_t avail) noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr int K = JordanMLP<T>::chunk_ticks();
        constexpr int NSM = NLP >= 0 ? 2 * NLP + NABS + 3 : 2 * kMaxTaus + kMaxTaus + 3;
        const int mv = m - m % NL;  // ticks in whole vectors
        if (mv == 0) return features_chunk_scalar(x0, sr, si, 1, 0, m);
        T* out = net_.staging();
        const int ns = NLP >= 0 ? NSM : ns_;
        V bad{};
        for (int r0 = 0; r0 < n_r_; r0 += NL) {
            const int nr = n_r_ - r0 < NL ? n_r_ - r0 : NL;  // real ridges in the lanes
            V z[NSM] = {};
            for (int j = 0; j < ns; ++j) z[j] = simd::load<V>(st_ + j * rs_ + r0);  // ghost lanes: zero
            for (int t = 0; t < mv; t += NL) {
                V x[4][NL];
                _Pragma("GCC unroll 4") for (int c = 0; c < 4; ++c) {
                    _Pragma("GCC unroll 16") for (int l = 0; l < NL; ++l) {
                        if (l < nr) {
                            const T* row = x0 + (r0 + l) * sr + c * si;
                            // The next chunk's cache line: with 4 rows per ridge and the
                            // outputs' rows, more streams than the hardware prefetcher follows.
                            if (t + K < avail && (t * int(sizeof(T))) % 64 == 0) __builtin_prefetch(row + t + K, 0, 3);
                            x[c][l] = simd::load<V>(row + t);
                            simd::store(out + (std::size_t(r0 + l) * ni_ + c) * K + t, x[c][l]);
                        } else {
                            x[c][l] = V{};
                        }
                        bad += x[c][l] * T(0);
                    }
                    simd::transpose(x[c]);
                }
                V f[NSM][NL];  // filter j at tick t + q, a vector of ridges
                _Pragma("GCC unroll 16") for (int q = 0; q < NL; ++q) {
                    lanes_tick<B, NLP, NABS>(z, x[0][q], x[1][q]);
                    _Pragma("GCC unroll 32") for (int k = 0; k < ns; ++k) f[k][q] = z[k];
                }
                _Pragma("GCC unroll 32") for (int k = 0; k < ns; ++k) {
                    simd::transpose(f[k]);
                    for (int l = 0; l < nr; ++l) simd::store(out + (std::size_t(r0 + l) * ni_ + 4 + k) * K + t, f[k][l]);
                }
            }
            for (int j = 0; j < ns; ++j) simd::store(st_ + j * rs_ + r0, z[j]);  // ghost lanes stay zero
        }
        T b = 0;
        for (int l = 0; l < NL; ++l) b += bad[l];
        if (mv < m) b += features_chunk_scalar(x0, sr, si, 1, mv, m);
        return b;
    }

    JordanMLP<T> net_;
    int n_r_, n_lp_, n_abs_, nf_, ni_, ns_;
    bool pad_mean_ = false;
    T a_lp_[kMaxTaus] = {}, g_lp_[kMaxTaus] = {}, a_abs_[kMaxTaus] = {}, g_abs_[kMaxTaus] = {};
    T b_ = 0, c_ = 0, inv_fs_ = 0;
    // 1 / knee per input, zero past the last (read a whole vector at a time from any input
    // on: features_tick's pad means)
    T ik_[kMaxInputs + 16] = {};
    bool compress_ = false;
    std::size_t rs_ = 0;  // ridge stride of st_ and feat_ (a multiple of 32 bytes of T)
    std::unique_ptr<void, detail::AlignedFree> buf_;
    T* st_ = nullptr;    // filter states, (ns_, rs_) lane-major, ghost lanes zero
    T* feat_ = nullptr;  // step()'s inputs, (ni_, rs_) feature-major
    T* raw_ = nullptr;   // a compressed pad-mean bank's raw features, (nf_, rs_): the mean's terms
};

}  // namespace detector
}  // namespace tactile
