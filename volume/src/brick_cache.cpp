#include "octoray/volume/brick_cache.h"

#include <iterator>
#include <stdexcept>

namespace octoray::volume {

BrickCache::BrickCache(uint64_t budgetBytes) : budgetBytes_(budgetBytes) {}

std::shared_ptr<const Brick> BrickCache::find(int64_t id) {
  const std::lock_guard lock(mutex_);
  const auto it = index_.find(id);
  if (it == index_.end()) {
    ++stats_.misses;
    return nullptr;
  }
  ++stats_.hits;
  lru_.splice(lru_.begin(), lru_, it->second);  // iterators stay valid across splice
  return it->second->brick;
}

bool BrickCache::insert(std::shared_ptr<const Brick> brick) {
  if (!brick) throw std::invalid_argument("BrickCache::insert: null brick");
  const uint64_t bytes = brick->byteSize();
  const int64_t id = brick->nodeId;
  Lru dropped;  // declared before the lock: evicted bricks are freed after it is released
  const std::lock_guard lock(mutex_);
  if (bytes > budgetBytes_) {
    ++stats_.rejected;
    return false;
  }
  if (const auto it = index_.find(id); it != index_.end()) {
    stats_.bytes -= it->second->bytes;
    dropped.splice(dropped.end(), lru_, it->second);
    index_.erase(it);
  }
  lru_.push_front(Entry{std::move(brick), bytes});
  index_.emplace(id, lru_.begin());
  stats_.bytes += bytes;
  evictToBudgetLocked(dropped);
  return true;
}

bool BrickCache::contains(int64_t id) const {
  const std::lock_guard lock(mutex_);
  return index_.contains(id);
}

bool BrickCache::erase(int64_t id) {
  Lru dropped;
  const std::lock_guard lock(mutex_);
  const auto it = index_.find(id);
  if (it == index_.end()) return false;
  stats_.bytes -= it->second->bytes;
  dropped.splice(dropped.end(), lru_, it->second);
  index_.erase(it);
  return true;
}

void BrickCache::clear() {
  Lru dropped;  // released after the lock, so brick destructors never run under it
  {
    const std::lock_guard lock(mutex_);
    dropped.swap(lru_);
    index_.clear();
    stats_.bytes = 0;
  }
}

void BrickCache::setBudget(uint64_t budgetBytes) {
  Lru dropped;
  const std::lock_guard lock(mutex_);
  budgetBytes_ = budgetBytes;
  evictToBudgetLocked(dropped);
}

uint64_t BrickCache::budgetBytes() const {
  const std::lock_guard lock(mutex_);
  return budgetBytes_;
}

BrickCacheStats BrickCache::stats() const {
  const std::lock_guard lock(mutex_);
  BrickCacheStats s = stats_;
  s.budgetBytes = budgetBytes_;
  s.count = lru_.size();
  return s;
}

void BrickCache::resetCounters() {
  const std::lock_guard lock(mutex_);
  stats_.hits = stats_.misses = stats_.evictions = stats_.rejected = 0;
}

std::vector<int64_t> BrickCache::idsByRecency() const {
  const std::lock_guard lock(mutex_);
  std::vector<int64_t> ids;
  ids.reserve(lru_.size());
  for (const Entry& e : lru_) ids.push_back(e.brick->nodeId);
  return ids;
}

void BrickCache::evictToBudgetLocked(Lru& dropped) {
  while (stats_.bytes > budgetBytes_ && !lru_.empty()) {
    const Entry& victim = lru_.back();
    stats_.bytes -= victim.bytes;
    index_.erase(victim.brick->nodeId);
    dropped.splice(dropped.end(), lru_, std::prev(lru_.end()));
    ++stats_.evictions;
  }
}

}  // namespace octoray::volume
