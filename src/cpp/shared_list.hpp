// Two threads sharing a list of independent jobs: the ridges of a pad stepped in one
// call (bind_contact.cpp).
//
// SharedList::run(items, count, fn, two) calls fn(item) once for every item, on the
// calling thread and, with two = true, on a second thread the object starts at its
// first such call and keeps. The caller takes items from the front of the list, the
// second thread from the back, one at a time, until they meet:
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
// fn returns false on a failure: no further item is started (items already started run
// to their end; fn records what ran). run() returns when every item started has ended.
// Nothing is allocated per call; the thread is started once, and joined by the
// destructor.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>

namespace tactile {

// A hint to the core that this thread is polling (x86: pause; elsewhere: give way).
inline void cpu_relax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
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
    SharedList(SharedList&&) noexcept = default;
    SharedList& operator=(SharedList&&) noexcept = default;
    ~SharedList() {
        if (!w_) return;
        {
            std::lock_guard<std::mutex> lk(w_->mu);
            w_->quit.store(true);
        }
        w_->wake.notify_all();
        w_->th.join();
    }

    // fn(item) -> bool for item in items[0, count); two: share them with the second thread
    template <class F>
    void run(const std::size_t* items, std::size_t count, F& fn, bool two) {
        List q(items, count);
        Share<F> share{&q, &fn};
        two = two && count >= 2;
        if (two) {
            start();
            post(&Share<F>::call, &share);
        }
        q.drain(fn, false);
        if (two) finish();
    }

    // lists the second thread took and ran (for tests: the sharing happens)
    std::uint64_t lists_taken() const noexcept { return w_ ? w_->ran.load() : 0; }

private:
    // items[front, back) are left; the caller takes the front, the worker the back
    struct List {
        const std::size_t* items;
        std::atomic<std::uint64_t> ends;  // front | back << 32
        std::atomic<bool> failed{false};
        List(const std::size_t* it, std::size_t count) : items(it), ends(static_cast<std::uint64_t>(count) << 32) {}
        template <class F>
        void drain(F& fn, bool from_back) {
            while (!failed.load(std::memory_order_relaxed)) {
                std::uint64_t e = ends.load(std::memory_order_relaxed), rest;
                std::size_t i;
                do {
                    const std::uint64_t front = e & 0xffffffffu, back = e >> 32;
                    if (front >= back) return;
                    i = static_cast<std::size_t>(from_back ? back - 1 : front);
                    rest = from_back ? e - (std::uint64_t{1} << 32) : e + 1;
                } while (!ends.compare_exchange_weak(e, rest, std::memory_order_relaxed));
                if (!fn(items[i])) failed.store(true, std::memory_order_relaxed);
            }
        }
    };
    template <class F>
    struct Share {  // the worker's part of one list
        List* q;
        F* fn;
        static void call(void* v) {
            Share* s = static_cast<Share*>(v);
            s->q->drain(*s->fn, true);
        }
    };
    struct Worker {
        std::thread th;
        std::mutex mu;
        std::condition_variable wake, idle;
        // list generations: posted by the caller, taken by the worker (or closed by the
        // caller); written under mu, read without it by the worker's polling
        std::atomic<std::uint64_t> posted{0}, taken{0}, ran{0};
        std::atomic<bool> quit{false};
        bool busy = false;
        void (*fn)(void*) = nullptr;
        void* arg = nullptr;
        bool pending() const noexcept { return posted.load() != taken.load(); }
    };
    std::unique_ptr<Worker> w_;

    void start() {
        if (w_) return;
        w_ = std::make_unique<Worker>();
        Worker* w = w_.get();
        w->th = std::thread([w] {
            std::unique_lock<std::mutex> lk(w->mu);
            for (;;) {
                if (!w->pending() && !w->quit.load()) {
                    lk.unlock();
                    const auto t0 = std::chrono::steady_clock::now();
                    while (!w->pending() && !w->quit.load(std::memory_order_relaxed) &&
                           std::chrono::steady_clock::now() - t0 < kSpin)
                        cpu_relax();
                    lk.lock();
                }
                w->wake.wait(lk, [w] { return w->quit.load() || w->pending(); });
                if (w->quit.load()) return;
                w->taken.store(w->posted.load());
                w->busy = true;
                void (*fn)(void*) = w->fn;
                void* arg = w->arg;
                lk.unlock();
                fn(arg);
                w->ran.fetch_add(1);
                lk.lock();
                w->busy = false;
                w->idle.notify_all();
            }
        });
    }
    void post(void (*fn)(void*), void* arg) {
        {
            std::lock_guard<std::mutex> lk(w_->mu);
            w_->fn = fn;
            w_->arg = arg;
            w_->posted.fetch_add(1);
        }
        w_->wake.notify_one();
    }
    // after the caller's part: close the list if the worker has not taken it, else wait
    // until the worker is done with it (it is awake then: a short wait)
    void finish() {
        std::unique_lock<std::mutex> lk(w_->mu);
        if (w_->pending()) {
            w_->taken.store(w_->posted.load());
            return;
        }
        w_->idle.wait(lk, [this] { return !w_->busy; });
    }
};

}  // namespace tactile
