// SharedList (src/cpp/shared_list.hpp) under ThreadSanitizer or AddressSanitizer: lists
// of items of random cost shared by the caller and the second thread, with pauses that
// let the second thread fall asleep, failing items, and the object destroyed while its
// thread polls. Checked:
//
// * every item runs at most once per list, and every item does without a failure;
// * with failures, every item before the first failing one (in list order) runs, so the
//   first failure seen is the one a single thread meets, whatever the timing;
// * after each pause the second thread wakes up and takes part in the next list (an item
//   from the front waits, with a timeout, until one from the back has started: a lost
//   wake-up fails here instead of passing by the caller doing everything);
// * the per-item data written by either thread is ordered by the object (ThreadSanitizer
//   reports a race otherwise), and no stack object is read after run() returned
//   (AddressSanitizer with detect_stack_use_after_return).
//
//     test_shared_list [rounds]
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <thread>
#include <vector>

#include "check.hpp"
#include "shared_list.hpp"

namespace {

double work(unsigned units) noexcept {  // about units microseconds of arithmetic
    double s = 0.0;
    for (unsigned i = 0; i < units * 200u; ++i) s += 1.0 / (1.0 + i);
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    const int rounds = argc > 1 ? std::atoi(argv[1]) : 20000;
    std::mt19937 rng(7);
    std::vector<std::size_t> items(8);
    std::vector<int> runs(8);  // plain ints: written by whichever thread runs the item
    std::vector<unsigned> cost(8);
    std::vector<char> fails(8);
    std::vector<double> out(8);  // the work's results, so that it is done
    std::atomic<bool> back_started{false};
    int wakeups = 0, wakeup_checks = 0;
    std::uint64_t taken = 0;
    {
        tactile::SharedList pool;
        bool after_pause = false;
        for (int r = 0; r < rounds; ++r) {
            const bool two = r % 5 != 0;  // every fifth list on the caller alone
            const bool rendezvous = after_pause && two;
            const std::size_t count = rendezvous ? 2 + rng() % 6 : rng() % 8;
            for (std::size_t i = 0; i < count; ++i) {
                items[i] = (i * 5 + static_cast<std::size_t>(r)) % 8;  // a permutation of 0..7, cut
                cost[i] = rng() % 4 == 0 ? 1 + rng() % 200 : rng() % 3;
            }
            for (int& v : runs) v = 0;
            for (char& f : fails) f = 0;
            std::size_t first_fail = count;  // list position of the first failing item
            if (!rendezvous && count > 0 && rng() % 8 == 0) {
                const int n_fail = 1 + static_cast<int>(rng() % 3);
                for (int k = 0; k < n_fail; ++k) {
                    const std::size_t pos = rng() % count;
                    fails[items[pos]] = 1;
                    if (pos < first_fail) first_fail = pos;
                }
            }
            back_started.store(false);
            bool met = false;
            auto fn = [&](std::size_t item) noexcept {
                std::size_t pos = 0;
                while (items[pos] != item) ++pos;
                if (rendezvous) {
                    if (pos == count - 1) back_started.store(true);  // the worker's first item
                    if (pos == 0) {  // the caller's first: wait for the worker, at most 1 s
                        const auto t0 = std::chrono::steady_clock::now();
                        while (!back_started.load() && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(1))
                            tactile::cpu_relax();
                        met = back_started.load();
                    }
                }
                out[item] = work(cost[pos]);
                runs[item] += 1;
                return !fails[item];
            };
            pool.run(items.data(), count, fn, two);
            int total = 0;
            for (std::size_t i = 0; i < count; ++i) {
                CHECK(runs[items[i]] <= 1, "round %d: item %zu ran %d times", r, items[i], runs[items[i]]);
                total += runs[items[i]];
                if (i <= first_fail && i < count)
                    CHECK(runs[items[i]] == 1, "round %d: item at %zu (before or at the first failure, %zu) did not run",
                          r, i, first_fail);
            }
            for (std::size_t i = count; i < 8; ++i)
                CHECK(runs[(i * 5 + static_cast<std::size_t>(r)) % 8] == 0, "round %d: an item not listed ran", r);
            if (first_fail == count) {
                CHECK(total == static_cast<int>(count), "round %d: %d of %zu items ran", r, total, count);
            } else if (!two) {  // one thread stops at the first failure
                CHECK(total == static_cast<int>(first_fail + 1), "round %d: %d items ran, the first failure at %zu",
                      r, total, first_fail);
            }
            if (rendezvous) {
                ++wakeup_checks;
                wakeups += met;
                CHECK(met, "round %d: the second thread did not take part after a pause (a lost wake-up?)", r);
            }
            after_pause = false;
            if (r % 97 == 0) {  // longer than the polling: the second thread sleeps and must be woken
                std::this_thread::sleep_for(tactile::SharedList::kSpin + std::chrono::milliseconds(1));
                after_pause = true;
            }
        }
        taken = pool.items_taken();
        CHECK(taken > 0, "the second thread ran no item in %d rounds", rounds);
        // destroyed while its thread polls (the last list just ended)
        std::vector<std::size_t> pair = {0, 1};
        auto quick = [&](std::size_t item) noexcept {
            runs[item] += 1;
            return true;
        };
        pool.run(pair.data(), pair.size(), quick, true);
    }
    {
        tactile::SharedList idle;  // never started: nothing to join
        std::vector<std::size_t> one = {3};
        int hit = 0;
        auto fn = [&](std::size_t) noexcept {
            ++hit;
            return true;
        };
        idle.run(one.data(), one.size(), fn, true);  // one item: no second thread
        CHECK(hit == 1 && idle.items_taken() == 0, "a single item ran %d times", hit);
        tactile::SharedList moved(std::move(idle));  // a pad is moved into place once
        moved.run(one.data(), one.size(), fn, false);
        CHECK(hit == 2, "after a move the list ran %d times", hit);
    }
    std::printf("items run by the second thread: %llu; it woke up after %d of %d pauses\n",
                static_cast<unsigned long long>(taken), wakeups, wakeup_checks);
    std::printf("ok: %d failures\n", failures);
    return failures ? 1 : 0;
}
