#include "octoray/volume/brick_loader.h"

#include <cmath>
#include <exception>
#include <limits>
#include <stdexcept>
#include <utility>

#include <fmt/format.h>

namespace octoray::volume {

// What one worker got for one id, before it is published under the lock.
struct BrickLoader::Outcome {
  std::shared_ptr<const Brick> brick;  // null when already cached or failed
  std::string error;                   // non-empty when failed
};

BrickLoader::BrickLoader(const StoreReader& store, BrickCache& cache, BrickLoaderOptions options)
    : store_(store), cache_(cache), options_(std::move(options)), paused_(options_.startPaused) {
  if (options_.threads < 1) {
    throw std::invalid_argument(
        fmt::format("BrickLoader: {} threads requested, at least 1 needed", options_.threads));
  }
  workers_.reserve(static_cast<std::size_t>(options_.threads));
  try {
    for (int i = 0; i < options_.threads; ++i) workers_.emplace_back([this] { workerLoop(); });
  } catch (...) {
    // A thread failed to start: stop the ones that did before the members go away.
    {
      const std::lock_guard lock(mutex_);
      stopping_ = true;
    }
    workAvailable_.notify_all();
    for (std::thread& t : workers_) t.join();
    throw;
  }
}

BrickLoader::~BrickLoader() {
  {
    const std::lock_guard lock(mutex_);
    stopping_ = true;
    queue_.clear();
    queuedById_.clear();
    for (auto& [id, cancelled] : loading_) cancelled = true;
  }
  workAvailable_.notify_all();
  for (std::thread& t : workers_) t.join();
}

bool BrickLoader::request(int64_t id, float priority) {
  const std::lock_guard lock(mutex_);
  return requestLocked(id, priority);
}

void BrickLoader::setRequests(std::span<const LoadRequest> requests) {
  const std::lock_guard lock(mutex_);
  // Validate first so that a bad id leaves the queue as it was.
  for (const LoadRequest& r : requests) {
    if (r.id < 0 || r.id >= static_cast<int64_t>(store_.nodes().size())) {
      throw std::out_of_range(fmt::format("BrickLoader: node {} is outside the store {} ({} nodes)",
                                          r.id, store_.path(), store_.nodes().size()));
    }
  }
  std::unordered_map<int64_t, std::set<Queued>::iterator> stale;
  stale.swap(queuedById_);
  for (const LoadRequest& r : requests) {
    if (const auto it = stale.find(r.id); it != stale.end()) {
      queuedById_.insert(stale.extract(it));  // still wanted: keep its place unless re-ranked
    }
  }
  for (const auto& [id, it] : stale) queue_.erase(it);
  for (const LoadRequest& r : requests) requestLocked(r.id, r.priority);
}

bool BrickLoader::requestLocked(int64_t id, float priority) {
  if (id < 0 || id >= static_cast<int64_t>(store_.nodes().size())) {
    throw std::out_of_range(fmt::format("BrickLoader: node {} is outside the store {} ({} nodes)",
                                        id, store_.path(), store_.nodes().size()));
  }
  // NaN would break the queue's strict weak ordering.
  if (std::isnan(priority)) priority = -std::numeric_limits<float>::infinity();
  if (const auto it = loading_.find(id); it != loading_.end()) {
    it->second = false;  // asked for again while loading: a cancelled load counts once more
    return false;
  }
  if (const auto it = queuedById_.find(id); it != queuedById_.end()) {
    if (it->second->priority == priority) return true;  // unchanged: keeps its place
    queue_.erase(it->second);
    it->second = queue_.insert(Queued{priority, nextSequence_++, id}).first;
    return true;
  }
  if (cache_.contains(id)) return false;
  queuedById_.emplace(id, queue_.insert(Queued{priority, nextSequence_++, id}).first);
  if (!paused_) workAvailable_.notify_one();
  return true;
}

void BrickLoader::dequeueLocked(int64_t id) {
  const auto it = queuedById_.find(id);
  queue_.erase(it->second);
  queuedById_.erase(it);
}

bool BrickLoader::cancel(int64_t id) {
  const std::lock_guard lock(mutex_);
  if (queuedById_.contains(id)) {
    dequeueLocked(id);
    if (idleLocked()) becameIdle_.notify_all();
    return true;
  }
  if (const auto it = loading_.find(id); it != loading_.end() && !it->second) {
    it->second = true;
    return true;
  }
  return false;
}

void BrickLoader::cancelAll() {
  const std::lock_guard lock(mutex_);
  queue_.clear();
  queuedById_.clear();
  for (auto& [id, cancelled] : loading_) cancelled = true;
  if (idleLocked()) becameIdle_.notify_all();
}

void BrickLoader::pause() {
  const std::lock_guard lock(mutex_);
  paused_ = true;
}

void BrickLoader::resume() {
  {
    const std::lock_guard lock(mutex_);
    paused_ = false;
  }
  workAvailable_.notify_all();
}

std::vector<int64_t> BrickLoader::poll() {
  const std::lock_guard lock(mutex_);
  return std::exchange(completed_, {});
}

std::vector<LoadError> BrickLoader::takeErrors() {
  const std::lock_guard lock(mutex_);
  return std::exchange(errors_, {});
}

void BrickLoader::waitIdle() {
  std::unique_lock lock(mutex_);
  becameIdle_.wait(lock, [this] { return idleLocked(); });
}

bool BrickLoader::waitIdle(std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  return becameIdle_.wait_for(lock, timeout, [this] { return idleLocked(); });
}

bool BrickLoader::isQueued(int64_t id) const {
  const std::lock_guard lock(mutex_);
  return queuedById_.contains(id);
}

BrickLoaderStats BrickLoader::stats() const {
  const std::lock_guard lock(mutex_);
  BrickLoaderStats s = stats_;
  s.queued = queue_.size();
  s.loading = loading_.size();
  return s;
}

bool BrickLoader::idleLocked() const {
  return queue_.empty() && loading_.empty() && callbacksRunning_ == 0;
}

void BrickLoader::workerLoop() {
  std::unique_lock lock(mutex_);
  for (;;) {
    workAvailable_.wait(lock, [this] { return stopping_ || (!paused_ && !queue_.empty()); });
    if (stopping_) return;
    const int64_t id = queue_.begin()->id;
    dequeueLocked(id);
    loading_.emplace(id, false);
    lock.unlock();
    Outcome outcome = load(id);
    lock.lock();
    finish(id, std::move(outcome), lock);
  }
}

BrickLoader::Outcome BrickLoader::load(int64_t id) const {
  Outcome outcome;
  if (cache_.contains(id)) return outcome;  // inserted by someone else since it was queued
  try {
    if (options_.beforeLoad) options_.beforeLoad(id);
    outcome.brick = std::make_shared<const Brick>(store_.readBrick(id));
  } catch (const std::exception& e) {
    outcome.error = e.what();
  } catch (...) {
    outcome.error = fmt::format("{}: node {}: unknown error while reading", store_.path(), id);
  }
  return outcome;
}

// Publishes one outcome (unless cancelled meanwhile), then runs the callback without the lock.
void BrickLoader::finish(int64_t id, Outcome outcome, std::unique_lock<std::mutex>& lock) {
  const auto it = loading_.find(id);
  const bool cancelled = it->second;
  loading_.erase(it);
  if (cancelled) {
    if (idleLocked()) becameIdle_.notify_all();
    return;
  }
  if (outcome.brick) {
    const uint64_t bytes = outcome.brick->byteSize();
    // Inserted under our lock, so a cancel() that returned first is never undone by it.
    if (cache_.insert(outcome.brick)) {
      ++stats_.loaded;
      stats_.bytesLoaded += bytes;
    } else {
      outcome.error = fmt::format("{}: node {}: brick of {} bytes exceeds the cache budget ({})",
                                  store_.path(), id, bytes, cache_.budgetBytes());
    }
  }
  std::function<void()> callback;
  if (outcome.error.empty()) {
    completed_.push_back(id);
    if (options_.onLoaded) callback = [this, id] { options_.onLoaded(id); };
  } else {
    ++stats_.failed;
    errors_.push_back(LoadError{id, outcome.error});
    if (options_.onError) {
      callback = [this, error = errors_.back()] { options_.onError(error); };
    }
  }
  if (callback) {
    ++callbacksRunning_;
    lock.unlock();
    std::string callbackError;
    try {
      callback();
    } catch (const std::exception& e) {
      callbackError = e.what();
    } catch (...) {
      callbackError = "unknown exception";
    }
    lock.lock();
    --callbacksRunning_;
    // A throwing callback is the caller's bug; report it rather than end the process.
    if (!callbackError.empty()) {
      ++stats_.failed;
      errors_.push_back(LoadError{id, "loader callback threw: " + callbackError});
    }
  }
  if (idleLocked()) becameIdle_.notify_all();
}

}  // namespace octoray::volume
