// The CPU brick cache: exact LRU eviction under a byte budget, bricks that outlive their
// eviction, and consistency under many threads.
#include <gtest/gtest.h>

#include <atomic>
#include <random>
#include <thread>

#include "octoray/volume/brick_cache.h"

namespace octoray::volume {
namespace {

// A brick of `samples` UInt16 values, every one equal to the id (checkable after sharing).
std::shared_ptr<const Brick> makeBrick(int64_t id, std::size_t samples = 100) {
  auto brick = std::make_shared<Brick>();
  brick->nodeId = id;
  brick->u16.assign(samples, static_cast<uint16_t>(id));
  return brick;
}

uint64_t bytesOf(std::size_t samples) { return makeBrick(0, samples)->byteSize(); }

using Ids = std::vector<int64_t>;

TEST(BrickCache, EvictsLeastRecentlyUsedInExactOrder) {
  const uint64_t one = bytesOf(100);
  BrickCache cache(3 * one);
  for (int64_t id : {0, 1, 2}) EXPECT_TRUE(cache.insert(makeBrick(id)));
  EXPECT_EQ(cache.idsByRecency(), (Ids{2, 1, 0}));
  ASSERT_NE(cache.find(0), nullptr);  // 0 becomes the most recent; 1 is now the oldest
  EXPECT_EQ(cache.idsByRecency(), (Ids{0, 2, 1}));

  EXPECT_TRUE(cache.insert(makeBrick(3)));
  EXPECT_EQ(cache.idsByRecency(), (Ids{3, 0, 2}));
  EXPECT_FALSE(cache.contains(1));

  ASSERT_NE(cache.find(2), nullptr);
  EXPECT_TRUE(cache.insert(makeBrick(4)));
  EXPECT_EQ(cache.idsByRecency(), (Ids{4, 2, 3}));
  EXPECT_EQ(cache.find(1), nullptr);
  EXPECT_EQ(cache.find(0), nullptr);

  const BrickCacheStats s = cache.stats();
  EXPECT_EQ(s.hits, 2u);
  EXPECT_EQ(s.misses, 2u);
  EXPECT_EQ(s.evictions, 2u);
  EXPECT_EQ(s.count, 3u);
  EXPECT_EQ(s.bytes, 3 * one);
  EXPECT_EQ(s.budgetBytes, 3 * one);
}

TEST(BrickCache, ByteBudgetCountsBytesNotBricks) {
  const uint64_t small = bytesOf(100), big = bytesOf(150);
  ASSERT_LT(small, big);
  ASSERT_LT(big, 2 * small);
  BrickCache cache(2 * small + big);
  for (int64_t id : {0, 1, 2}) cache.insert(makeBrick(id, 100));
  // 3 small + big is over budget by less than one small brick: only the oldest goes.
  cache.insert(makeBrick(10, 150));
  EXPECT_EQ(cache.idsByRecency(), (Ids{10, 2, 1}));
  EXPECT_EQ(cache.stats().bytes, 2 * small + big);
  // A second big one needs the room of two small ones.
  cache.insert(makeBrick(11, 150));
  EXPECT_EQ(cache.idsByRecency(), (Ids{11, 10}));
  EXPECT_EQ(cache.stats().bytes, 2 * big);
  EXPECT_EQ(cache.stats().evictions, 3u);
}

TEST(BrickCache, BrickLargerThanBudgetIsReturnedButNotKept) {
  BrickCache cache(bytesOf(100));
  cache.insert(makeBrick(1));
  const auto huge = makeBrick(2, 1000);
  EXPECT_FALSE(cache.insert(huge));
  EXPECT_FALSE(cache.contains(2));
  EXPECT_TRUE(cache.contains(1));  // nothing was evicted to make room that could not suffice
  EXPECT_EQ(huge->u16.size(), 1000u);
  EXPECT_EQ(huge.use_count(), 1);  // the cache holds no reference
  EXPECT_EQ(cache.stats().rejected, 1u);
  EXPECT_EQ(cache.stats().evictions, 0u);
}

TEST(BrickCache, HeldBrickStaysValidAfterEviction) {
  BrickCache cache(bytesOf(100));
  cache.insert(makeBrick(7));
  std::shared_ptr<const Brick> held = cache.find(7);
  ASSERT_NE(held, nullptr);
  cache.insert(makeBrick(8));  // evicts 7
  EXPECT_FALSE(cache.contains(7));
  EXPECT_EQ(held->nodeId, 7);
  EXPECT_EQ(held->u16.size(), 100u);
  EXPECT_EQ(held->u16[99], 7);
  EXPECT_EQ(held.use_count(), 1);  // the caller is now the only owner
  const std::weak_ptr<const Brick> watch = held;
  held.reset();
  EXPECT_TRUE(watch.expired());  // and the cache leaked no reference
}

TEST(BrickCache, ReinsertReplacesAndTouches) {
  const uint64_t one = bytesOf(100);
  BrickCache cache(3 * one);
  for (int64_t id : {0, 1, 2}) cache.insert(makeBrick(id));
  const auto fresh = makeBrick(0);
  cache.insert(fresh);
  EXPECT_EQ(cache.idsByRecency(), (Ids{0, 2, 1}));
  EXPECT_EQ(cache.find(0), fresh);
  EXPECT_EQ(cache.stats().bytes, 3 * one);
  EXPECT_EQ(cache.stats().count, 3u);
  EXPECT_EQ(cache.stats().evictions, 0u);
}

TEST(BrickCache, ContainsDoesNotTouchOrCount) {
  BrickCache cache(2 * bytesOf(100));
  cache.insert(makeBrick(0));
  cache.insert(makeBrick(1));
  EXPECT_TRUE(cache.contains(0));
  EXPECT_FALSE(cache.contains(5));
  cache.insert(makeBrick(2));  // 0 is still the oldest despite contains()
  EXPECT_EQ(cache.idsByRecency(), (Ids{2, 1}));
  EXPECT_EQ(cache.stats().hits + cache.stats().misses, 0u);
}

TEST(BrickCache, SetBudgetEvictsOldestAndClearEmpties) {
  const uint64_t one = bytesOf(100);
  BrickCache cache(4 * one);
  for (int64_t id : {0, 1, 2, 3}) cache.insert(makeBrick(id));
  cache.find(0);
  cache.setBudget(2 * one);
  EXPECT_EQ(cache.idsByRecency(), (Ids{0, 3}));
  EXPECT_EQ(cache.budgetBytes(), 2 * one);
  EXPECT_EQ(cache.stats().evictions, 2u);

  EXPECT_TRUE(cache.erase(3));
  EXPECT_FALSE(cache.erase(3));
  EXPECT_EQ(cache.stats().bytes, one);

  cache.clear();
  EXPECT_EQ(cache.stats().count, 0u);
  EXPECT_EQ(cache.stats().bytes, 0u);
  EXPECT_EQ(cache.find(0), nullptr);
  EXPECT_EQ(cache.stats().evictions, 2u);  // clear and erase are not evictions
  cache.resetCounters();
  EXPECT_EQ(cache.stats().misses, 0u);
  EXPECT_EQ(cache.stats().evictions, 0u);
}

TEST(BrickCache, NullInsertIsRejected) {
  BrickCache cache(1000);
  EXPECT_THROW(cache.insert(nullptr), std::invalid_argument);
}

// Many threads look up and fill a cache much smaller than the id range: every brick found is
// the right one and whole, and the books balance at the end.
TEST(BrickCache, ConcurrentFindAndInsertStayConsistent) {
  constexpr int kThreads = 8, kOpsPerThread = 4000, kIds = 64, kCapacityBricks = 16;
  const uint64_t one = bytesOf(100);
  BrickCache cache(kCapacityBricks * one);
  std::atomic<int> wrong{0};
  std::atomic<uint64_t> finds{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      std::mt19937 rng(static_cast<unsigned>(t));
      std::uniform_int_distribution<int64_t> pick(0, kIds - 1);
      for (int op = 0; op < kOpsPerThread; ++op) {
        const int64_t id = pick(rng);
        if (op % 97 == 0) cache.contains(id);
        if (op % 501 == 0) cache.stats();
        std::shared_ptr<const Brick> b = cache.find(id);
        ++finds;
        if (!b) {
          b = makeBrick(id);
          cache.insert(b);
        }
        if (b->nodeId != id || b->u16.size() != 100 || b->u16[0] != id || b->u16[99] != id) {
          ++wrong;
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(wrong.load(), 0);
  const BrickCacheStats s = cache.stats();
  EXPECT_EQ(s.hits + s.misses, finds.load());
  EXPECT_GT(s.hits, 0u);
  EXPECT_GT(s.evictions, 0u);
  EXPECT_EQ(s.count, static_cast<std::size_t>(kCapacityBricks));
  EXPECT_EQ(s.bytes, s.count * one);
  EXPECT_EQ(cache.idsByRecency().size(), s.count);
}

}  // namespace
}  // namespace octoray::volume
