#pragma once
// The CPU level-2 brick cache (paper §4): decompressed bricks of one store, keyed by node id,
// kept in least-recently-used order under a byte budget. Bricks are shared immutable objects,
// so a caller holding one keeps it valid after the cache has evicted it. Thread-safe.

#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <unordered_map>
#include <vector>

#include "octoray/volume/store_reader.h"

namespace octoray::volume {

struct BrickCacheStats {
  uint64_t hits = 0;       // find() calls that returned a brick
  uint64_t misses = 0;     // find() calls that returned nullptr
  uint64_t evictions = 0;  // bricks dropped to stay under the budget
  uint64_t rejected = 0;   // insert() calls refused: the brick alone exceeds the budget
  uint64_t bytes = 0;      // Brick::byteSize() summed over cached bricks
  uint64_t budgetBytes = 0;
  std::size_t count = 0;  // cached bricks
};

class BrickCache {
 public:
  explicit BrickCache(uint64_t budgetBytes);
  BrickCache(const BrickCache&) = delete;
  BrickCache& operator=(const BrickCache&) = delete;

  // The cached brick of node `id`, now the most recently used one; nullptr when absent.
  std::shared_ptr<const Brick> find(int64_t id);

  // Caches `brick` under brick->nodeId as the most recently used one (replacing a brick
  // already cached under that id), then evicts least recently used bricks until the cache is
  // within budget. A brick larger than the whole budget is not kept (the cache is left as it
  // was) and false is returned; the caller's pointer stays valid either way.
  bool insert(std::shared_ptr<const Brick> brick);

  // Whether node `id` is cached; does not count as a use.
  bool contains(int64_t id) const;

  // Drops node `id` if cached (not counted as an eviction); true when it was cached.
  bool erase(int64_t id);

  // Drops every brick (not counted as evictions); counters are kept.
  void clear();

  // Changes the budget, evicting least recently used bricks until within it.
  void setBudget(uint64_t budgetBytes);
  uint64_t budgetBytes() const;

  BrickCacheStats stats() const;
  // Zeroes hits, misses, evictions and rejected (for per-frame figures).
  void resetCounters();

  // Cached node ids from most to least recently used (diagnostics and tests).
  std::vector<int64_t> idsByRecency() const;

 private:
  struct Entry {
    std::shared_ptr<const Brick> brick;
    uint64_t bytes = 0;  // brick->byteSize() at insertion; bricks are immutable
  };
  using Lru = std::list<Entry>;  // front = most recently used

  // Moves least recently used entries to `dropped` until within budget (mutex_ held).
  void evictToBudgetLocked(Lru& dropped);

  mutable std::mutex mutex_;
  Lru lru_;
  std::unordered_map<int64_t, Lru::iterator> index_;
  uint64_t budgetBytes_ = 0;
  BrickCacheStats stats_;
};

}  // namespace octoray::volume
