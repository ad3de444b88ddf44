// Cross-thread misuse detection for the stateful real-time objects.
//
// A stateful object (a filter cascade, a detector, a pipeline) is driven by one
// thread at a time. Serialising callers with a mutex would let a GUI or logging
// thread block the DAQ callback (priority inversion), so the objects are not
// locked: each call that reads or writes the state claims an atomic owner flag
// and a second concurrent caller gets an error ("used by another thread")
// instead of waiting. Claiming is one atomic exchange, releasing one store: no
// system call, no allocation, never blocks.
#pragma once

#include <atomic>

namespace tactile {

class OwnerFlag {
public:
    // True if the caller now owns the object; false if another thread does.
    bool try_claim() noexcept { return !busy_.exchange(true, std::memory_order_acquire); }
    void release() noexcept { busy_.store(false, std::memory_order_release); }
    bool busy() const noexcept { return busy_.load(std::memory_order_relaxed); }

private:
    std::atomic<bool> busy_{false};
};

// Scoped claim: owns() tells whether the claim succeeded; released on scope exit.
class OwnerClaim {
public:
    explicit OwnerClaim(OwnerFlag& f) noexcept : f_(f), owns_(f.try_claim()) {}
    ~OwnerClaim() {
        if (owns_) f_.release();
    }
    OwnerClaim(const OwnerClaim&) = delete;
    OwnerClaim& operator=(const OwnerClaim&) = delete;
    bool owns() const noexcept { return owns_; }

private:
    OwnerFlag& f_;
    bool owns_;
};

}  // namespace tactile
