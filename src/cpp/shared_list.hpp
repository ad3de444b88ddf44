// Two threads sharing a list of independent jobs: the ridges of a pad stepped in one
// call (bind_contact.cpp).
//
// SharedList::run(items, count, fn, two) calls fn(item) for the items, on the calling
// thread and, with two = true, on a second thread the object starts at its first such
// call and keeps. The caller takes items from the front of the list, the second thread
// from the back, one at a time, until they meet:
//
// * ridges differ in cost from call to call (a breakaway cascade is on one ridge), so
//   neither thread has a fixed half of them;
// * an item run call after call mostly stays on the same thread, so its data stays in
//   that core's cache (a ridge's factors are 1-2 MB at the default mesh: taking the
//   items from one shared front moved them between the cores and cost more than the
//   sharing gained on quiet ticks);
// * the caller never waits for the second thread to wake up: a list the worker has not
//   taken when the caller has run out of items is closed, and the worker skips it;
// * after a list the worker polls for the next one for kSpin before it sleeps: waking a
//   sleeping thread took 0.1 ms and more on a virtual machine, a tenth of a 1 kHz tick,
//   and a pad stepped tick by tick posts a list every tick. So while a pad is stepped at
//   500 Hz or more the second core stays busy.
//
// fn(item) -> bool must not throw (checked at compile time); false is a failure. The
// items after the first failing one in list order are not started (those already
// started run to their end), and every item before it runs: so which item is the first
// to fail does not depend on the threads' timing, and it is the one a single thread
// meets (fn records what ran). run() returns when every item started has ended.
// Nothing is allocated per call. If the second thread cannot be started, the items run
// on the caller. In a child process made by fork() the parent's thread is not there:
// the child starts its own and never joins the parent's.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <system_error>
#include <thread>
#include <utility>

#if defined(__unix__) || defined(__APPLE__)
#include <unistd.h>
#define TM_SHARED_LIST_PID() static_cast<long>(::getpid())
#else
#define TM_SHARED_LIST_PID() 0L
#endif

namespace tactile {

// A hint to the core that this thread is polling.
inline void cpu_relax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#elif defined(__aarch64__)
    __asm__ __volatile__("yield");
#else
    std::this_thread::yield();
#endif
}

class SharedList {
public:
    static constexpr std::chrono::milliseconds kSpin{2};

    SharedList() = default;
    SharedList(const SharedList&) = delete;
    SharedList& operator=(const SharedList&) = delete;
    SharedList(SharedList&& o) noexcept : w_(std::move(o.w_)) {}
    SharedList& operator=(SharedList&&) = delete;
    ~SharedList() { stop(); }

    // fn(item) -> bool for the items[0, count) (see above); two: share them with the
    // second thread
    template <class F>
    void run(const std::size_t* items, std::size_t count, F& fn, bool two) {
        static_assert(noexcept(fn(std::size_t{})), "SharedList::run: fn must be noexcept");
        List q(items, count);
        Share<F> share{&q, &fn};
        two = two && count >= 2 && start();
        if (two) {
            q.counter = &w_->items;
            post(&Share<F>::call, &share);
        }
        q.drain(fn, false);
        if (two) finish();
    }

    // items the second thread has run (for tests: the sharing happens)
    std::uint64_t items_taken() const noexcept { return w_ ? w_->items.load() : 0; }

private:
    // items[front, back) are left; the caller takes the front, the worker the back.
    // stop: the list position of the first failure so far (count: none)
    struct List {
        const std::size_t* items;
        std::atomic<std::uint64_t> ends;  // front | back << 32
        std::atomic<std::size_t> stop;
        std::atomic<std::uint64_t>* counter = nullptr;  // the worker's item count
        List(const std::size_t* it, std::size_t count)
            : items(it), ends(static_cast<std::uint64_t>(count) << 32), stop(count) {}
        template <class F>
        void drain(F& fn, bool from_back) noexcept {
            for (;;) {
                std::uint64_t e = ends.load(std::memory_order_relaxed), rest;
                std::size_t i;
                do {
                    const std::uint64_t front = e & 0xffffffffu, back = e >> 32;
                    if (front >= back) return;
                    i = static_cast<std::size_t>(from_back ? back - 1 : front);
                    rest = from_back ? e - (std::uint64_t{1} << 32) : e + 1;
                } while (!ends.compare_exchange_weak(e, rest, std::memory_order_relaxed));
                // after the first failure (so far) in list order: not started. stop only
                // falls, so every position below its final value is run by someone.
                if (i > stop.load(std::memory_order_relaxed)) continue;
                if (from_back && counter) counter->fetch_add(1, std::memory_order_relaxed);
                if (!fn(items[i])) {
                    std::size_t s = stop.load(std::memory_order_relaxed);
                    while (i < s && !stop.compare_exchange_weak(s, i, std::memory_order_relaxed)) {
                    }
                }
            }
        }
    };
    template <class F>
    struct Share {  // the worker's part of one list
        List* q;
        F* fn;
        static void call(void* v) noexcept {
            Share* s = static_cast<Share*>(v);
            s->q->drain(*s->fn, true);
        }
    };
    struct Worker {
        std::thread th;
        long pid = 0;  // the process that started it
        std::mutex mu;
        std::condition_variable wake, idle;
        // list generations: posted by the caller, taken by the worker (or closed by the
        // caller); written under mu, read without it by the worker's polling
        std::atomic<std::uint64_t> posted{0}, taken{0}, items{0};
        std::atomic<bool> quit{false}, busy{false};
        void (*fn)(void*) = nullptr;
        void* arg = nullptr;
        bool pending() const noexcept { return posted.load() != taken.load(); }
    };
    std::unique_ptr<Worker> w_;

    static void loop(Worker* w) {
        using clock = std::chrono::steady_clock;
        std::unique_lock<std::mutex> lk(w->mu, std::defer_lock);
        for (;;) {
            // poll for a list; a list seen but closed before the lock was had is activity
            // too: poll again rather than sleep
            const auto t0 = clock::now();
            bool timed_out = false;
            while (!w->pending() && !w->quit.load(std::memory_order_relaxed)) {
                if (clock::now() - t0 >= kSpin) {
                    timed_out = true;
                    break;
                }
                cpu_relax();
            }
            lk.lock();
            if (!w->pending() && !w->quit.load()) {
                if (!timed_out) {
                    lk.unlock();
                    continue;
                }
                // sleep until a list is posted (post() changes `posted` under the lock, so
                // none is missed); woken for a list the caller has closed meanwhile (or
                // for nothing), poll again: lists are coming
                w->wake.wait(lk);
                if (!w->pending() && !w->quit.load()) {
                    lk.unlock();
                    continue;
                }
            }
            if (w->quit.load()) return;
            w->taken.store(w->posted.load());
            w->busy.store(true);
            void (*fn)(void*) = w->fn;
            void* arg = w->arg;
            lk.unlock();
            fn(arg);
            lk.lock();
            w->busy.store(false, std::memory_order_release);
            w->idle.notify_all();
            lk.unlock();
        }
    }
    // In a child of fork() the parent's thread is not here, and its mutex may have been
    // copied locked: its worker is left as it is (not joined, not freed).
    void forget_inherited() noexcept {
        if (w_ && w_->pid != TM_SHARED_LIST_PID()) (void)w_.release();
    }
    // the second thread is running (started now if needed); false if it cannot be
    bool start() noexcept {
        forget_inherited();
        if (w_) return true;
        try {
            auto w = std::make_unique<Worker>();
            w->pid = TM_SHARED_LIST_PID();
            w->th = std::thread(&SharedList::loop, w.get());
            w_ = std::move(w);
            return true;
        } catch (...) {  // no thread (resources, or std::system_error): one thread does it all
            return false;
        }
    }
    void post(void (*fn)(void*), void* arg) noexcept {
        {
            std::lock_guard<std::mutex> lk(w_->mu);
            w_->fn = fn;
            w_->arg = arg;
            w_->posted.fetch_add(1);
        }
        w_->wake.notify_one();
    }
    // after the caller's part: close the list if the worker has not taken it, else wait
    // until the worker is done with it (it is awake then; the wait is the rest of the item
    // it is on). The wait polls first: sleeping and being woken cost tens of microseconds
    // on a virtual machine, more than most items.
    void finish() noexcept {
        std::unique_lock<std::mutex> lk(w_->mu);
        if (w_->pending()) {
            w_->taken.store(w_->posted.load());
            return;
        }
        lk.unlock();
        const auto t0 = std::chrono::steady_clock::now();
        while (w_->busy.load(std::memory_order_acquire)) {
            if (std::chrono::steady_clock::now() - t0 >= kSpin) {
                lk.lock();
                w_->idle.wait(lk, [this] { return !w_->busy.load(); });
                return;
            }
            cpu_relax();
        }
    }
    void stop() noexcept {
        forget_inherited();
        if (!w_) return;
        {
            std::lock_guard<std::mutex> lk(w_->mu);
            w_->quit.store(true);
        }
        w_->wake.notify_all();
        w_->th.join();
        w_.reset();
    }
};

}  // namespace tactile

#undef TM_SHARED_LIST_PID
