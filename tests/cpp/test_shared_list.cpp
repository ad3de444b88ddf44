// SharedList (src/cpp/shared_list.hpp) under ThreadSanitizer or AddressSanitizer: lists
// of items of random cost shared by the caller and the second thread, with pauses
// that let the second thread fall asleep, failures that stop the list, and the object
// destroyed while its thread polls. Every item must run exactly once per list (none
// after a failure has been seen by both threads), the per-item data written by either
// thread must be ordered by the object (TSan reports a race otherwise), and the second
// thread must take part.
//
//     test_shared_list [rounds]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <thread>
#include <vector>

#include "check.hpp"
#include "shared_list.hpp"

namespace {

double work(unsigned units) {  // about units microseconds of arithmetic
    double s = 0.0;
    for (unsigned i = 0; i < units * 200u; ++i) s += 1.0 / (1.0 + i);
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    const int rounds = argc > 1 ? std::atoi(argv[1]) : 20000;
    std::mt19937 rng(7);
    std::vector<std::size_t> items(8);
    std::vector<int> runs(8);          // plain ints: written by whichever thread runs the item
    std::vector<unsigned> cost(8);
    std::vector<double> out(8);  // the work's results, so that it is done
    std::uint64_t taken_before = 0;
    {
        tactile::SharedList pool;
        for (int r = 0; r < rounds; ++r) {
            const std::size_t count = rng() % 8;
            for (std::size_t i = 0; i < count; ++i) {
                items[i] = (i * 5 + static_cast<std::size_t>(r)) % 8;  // a permutation of 0..7, cut
                cost[i] = rng() % 4 == 0 ? 1 + rng() % 200 : rng() % 3;
            }
            for (int& v : runs) v = 0;
            const bool fail = rng() % 10 == 0 && count > 0;
            const std::size_t fail_at = fail ? items[rng() % count] : 99;
            auto fn = [&](std::size_t item) {
                std::size_t pos = 0;
                while (items[pos] != item) ++pos;
                out[item] = work(cost[pos]);
                runs[item] += 1;
                return item != fail_at;
            };
            pool.run(items.data(), count, fn, r % 5 != 0);  // every fifth list on the caller alone
            int total = 0;
            for (std::size_t i = 0; i < count; ++i) {
                CHECK(runs[items[i]] <= 1, "round %d: item %zu ran %d times", r, items[i], runs[items[i]]);
                total += runs[items[i]];
            }
            for (std::size_t i = count; i < 8; ++i)
                CHECK(runs[(i * 5 + static_cast<std::size_t>(r)) % 8] == 0, "round %d: an item not listed ran", r);
            if (!fail) {
                CHECK(total == static_cast<int>(count), "round %d: %d of %zu items ran", r, total, count);
            } else {
                CHECK(runs[fail_at] == 1, "round %d: the failing item did not run", r);
                if (r % 5 == 0) {  // on the caller alone the list stops at the failure, in order
                    std::size_t pos = 0;
                    while (items[pos] != fail_at) ++pos;
                    CHECK(total == static_cast<int>(pos + 1), "round %d: %d items ran, the failure was item %zu",
                          r, total, pos + 1);
                }
            }
            if (r % 97 == 0)  // longer than the polling: the second thread sleeps and must be woken
                std::this_thread::sleep_for(tactile::SharedList::kSpin + std::chrono::milliseconds(1));
        }
        taken_before = pool.lists_taken();
        CHECK(taken_before > 0, "the second thread took no list in %d rounds", rounds);
        // destroyed while its thread polls (the last list just ended)
        std::vector<std::size_t> two = {0, 1};
        auto quick = [&](std::size_t item) { runs[item] += 1; return true; };
        pool.run(two.data(), two.size(), quick, true);
    }
    {
        tactile::SharedList idle;  // never started: nothing to join
        std::vector<std::size_t> one = {3};
        int hit = 0;
        auto fn = [&](std::size_t) { ++hit; return true; };
        idle.run(one.data(), one.size(), fn, true);  // one item: no second thread
        CHECK(hit == 1 && idle.lists_taken() == 0, "a single item ran %d times", hit);
    }
    std::printf("lists taken by the second thread: %llu of %d\n", static_cast<unsigned long long>(taken_before), rounds);
    std::printf("ok: %d failures\n", failures);
    return failures ? 1 : 0;
}
