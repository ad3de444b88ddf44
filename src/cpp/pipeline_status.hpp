// The status of a pipeline: the counters and flags a tick updates (PipelineStatus),
// why a tick was rejected (RejectReason), and the board that publishes the status
// from the stepping thread to readers on any thread (StatusBoard).
#pragma once

#include <atomic>
#include <cstdint>
#include <cstring>

namespace tactile {

struct PipelineStatus {
    std::uint64_t ticks = 0;          // step() calls (accepted + rejected)
    std::uint64_t rejected = 0;       // rejected ticks
    std::uint64_t nonfinite = 0;      // rejected ticks with a NaN/Inf sample
    std::uint64_t out_of_range = 0;   // rejected ticks with a finite sample beyond its limit
    std::uint64_t overflow = 0;       // rejected ticks whose update would make a state non-finite
    std::int64_t last_bad_tick = -1;  // tick index of the last rejected tick
    int last_bad_channel = -1;        // first bad channel of that tick
    std::uint32_t consecutive_rejected = 0;
    bool fault = false;               // more than max_hold_ticks consecutive rejections
    bool slip = false;                // max y_slip >= slip_threshold at the last accepted tick
    bool at_limit = false;            // the command sits on a travel limit
    int last_reason = 0;              // RejectReason of the last rejected tick (0: none yet)
};

enum class RejectReason : int { none = 0, nonfinite = 1, out_of_range = 2, overflow = 3 };

inline const char* reject_reason_name(int r) noexcept {
    switch (r) {
        case 1: return "nonfinite";
        case 2: return "out_of_range";
        case 3: return "overflow";
        default: return "";
    }
}

// The status as last published by the stepping thread, readable from any thread
// without a lock and without tearing: a sequence lock over atomic words. There is
// one writer (the owner of the pipeline), so the count is kept in a plain member
// as well and the writer never reads an atomic or performs a read-modify-write:
// an odd count, the words (release stores: each one after the odd count), the
// even count (release store: after every word). On x86-64 that is plain moves and
// no fence instruction (and no fence for ThreadSanitizer to miss). A reader
// retries while a publication is under way.
//
// Per tick only the words a tick always changes are stored (ticks, the flags, the
// command); the rejection counters and the last bad tick are stored only when the
// caller says they changed (`counters`), i.e. after a rejected tick, a recovery
// from rejections, a reset. Words not stored keep their last published value, so
// a reader always sees one consistent status.
class StatusBoard {
public:
    void publish(const PipelineStatus& s, double position, double velocity, bool counters = true) noexcept {
        const std::uint64_t q = seq_w_;
        constexpr auto rel = std::memory_order_release;
        seq_.store(q + 1, std::memory_order_relaxed);
        words_[0].store(s.ticks, rel);
        words_[7].store(flags_word(s), rel);
        words_[8].store(bits(position), rel);
        words_[9].store(bits(velocity), rel);
        if (counters) {
            words_[1].store(s.rejected, rel);
            words_[2].store(s.nonfinite, rel);
            words_[3].store(s.out_of_range, rel);
            words_[4].store(s.overflow, rel);
            words_[5].store(std::uint64_t(s.last_bad_tick), rel);
            words_[6].store(std::uint64_t(std::uint32_t(s.last_bad_channel)) |
                                (std::uint64_t(s.consecutive_rejected) << 32), rel);
        }
        seq_w_ = q + 2;
        seq_.store(q + 2, std::memory_order_release);  // every word before the even count
    }
    PipelineStatus read(double* position, double* velocity) const noexcept {
        std::uint64_t w[kWords];
        for (;;) {
            const std::uint64_t q0 = seq_.load(std::memory_order_acquire);
            if (q0 & 1u) continue;  // a publication is under way: a few stores long
            // Acquire loads (plain loads on x86-64): the count is re-read after them.
            for (int i = 0; i < kWords; ++i) w[i] = words_[i].load(std::memory_order_acquire);
            if (seq_.load(std::memory_order_relaxed) == q0) break;
        }
        PipelineStatus s;
        s.ticks = w[0];
        s.rejected = w[1];
        s.nonfinite = w[2];
        s.out_of_range = w[3];
        s.overflow = w[4];
        s.last_bad_tick = std::int64_t(w[5]);
        s.last_bad_channel = int(std::int32_t(std::uint32_t(w[6])));
        s.consecutive_rejected = std::uint32_t(w[6] >> 32);
        s.fault = w[7] & 1u;
        s.slip = (w[7] >> 1) & 1u;
        s.at_limit = (w[7] >> 2) & 1u;
        s.last_reason = int(w[7] >> 8);
        if (position) std::memcpy(position, &w[8], sizeof(double));
        if (velocity) std::memcpy(velocity, &w[9], sizeof(double));
        return s;
    }

private:
    static constexpr int kWords = 10;
    static std::uint64_t flags_word(const PipelineStatus& s) noexcept {
        return std::uint64_t(s.fault) | (std::uint64_t(s.slip) << 1) | (std::uint64_t(s.at_limit) << 2) |
               (std::uint64_t(std::uint32_t(s.last_reason)) << 8);
    }
    static std::uint64_t bits(double v) noexcept {
        std::uint64_t w;
        std::memcpy(&w, &v, sizeof w);
        return w;
    }
    std::atomic<std::uint64_t> seq_{0};
    std::atomic<std::uint64_t> words_[kWords] = {};
    std::uint64_t seq_w_ = 0;  // the writer's copy of seq_
};

}  // namespace tactile
