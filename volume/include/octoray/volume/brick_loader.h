#pragma once
// Asynchronous brick loading (paper §4: "all data access requests are performed
// asynchronously by a separate thread, and refinement continues only if data is immediately
// available"). The refinement asks for the bricks it is missing, with their priorities, every
// frame; background threads read, verify and decompress the most urgent ones into the
// BrickCache and report them; the renderer picks them up on a later frame. Failures (a
// corrupted brick, an unreadable file) are reported per node, never thrown on a worker.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <set>
#include <span>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "octoray/volume/brick_cache.h"
#include "octoray/volume/store_reader.h"

namespace octoray::volume {

struct LoadRequest {
  int64_t id = -1;
  float priority = 0;  // larger first (e.g. projected voxel size on screen); NaN counts as lowest
};

struct LoadError {
  int64_t id = -1;
  std::string message;  // names the store file and what failed
};

struct BrickLoaderOptions {
  int threads = 1;           // background reader threads, >= 1
  bool startPaused = false;  // queue requests without loading until resume()
  // Called on a worker thread, without the loader's lock, after node `id` is in the cache.
  // It may call the loader's request/cancel/poll functions but must not destroy the loader.
  std::function<void(int64_t id)> onLoaded;
  // Called likewise when node `id` failed; the error is also kept for takeErrors().
  std::function<void(const LoadError&)> onError;
  // Called on a worker thread, without the lock, just before node `id` is read (tracing, and
  // a gate that lets tests hold a load in progress).
  std::function<void(int64_t id)> beforeLoad;
};

struct BrickLoaderStats {
  std::size_t queued = 0;    // requests waiting
  std::size_t loading = 0;   // requests being read right now
  uint64_t loaded = 0;       // bricks put into the cache
  uint64_t failed = 0;       // errors reported
  uint64_t bytesLoaded = 0;  // Brick::byteSize() of loaded bricks
};

class BrickLoader {
 public:
  // `store` and `cache` must outlive the loader. Throws std::invalid_argument for threads < 1.
  BrickLoader(const StoreReader& store, BrickCache& cache, BrickLoaderOptions options = {});
  // Drops queued requests, lets each worker finish (and discard) the brick it is reading,
  // and joins: bounded by one brick read per thread.
  ~BrickLoader();
  BrickLoader(const BrickLoader&) = delete;
  BrickLoader& operator=(const BrickLoader&) = delete;

  // Asks for node `id`. No-op (false) when it is cached or being loaded. A queued id takes the
  // new priority (re-prioritisation); equal priorities load in request order. Returns true
  // when the id is queued. Throws std::out_of_range for an id outside the store.
  bool request(int64_t id, float priority);
  // The frame's whole request set: queued ids not listed are dropped, listed ones are
  // requested as by request(). Ids being loaded are left to finish.
  void setRequests(std::span<const LoadRequest> requests);

  // Forgets node `id`: a queued request is dropped and a load in progress is discarded (not
  // cached, not reported). True when there was something to cancel.
  bool cancel(int64_t id);
  void cancelAll();

  // Workers take no new request while paused; loads in progress finish.
  void pause();
  void resume();

  // Ids put into the cache since the last call, in completion order.
  std::vector<int64_t> poll();
  // Errors since the last call, in order.
  std::vector<LoadError> takeErrors();

  // Blocks until nothing is queued or loading and no callback is running. While paused with
  // requests queued this waits for resume(); the timed form returns false on timeout.
  void waitIdle();
  bool waitIdle(std::chrono::milliseconds timeout);

  bool isQueued(int64_t id) const;
  BrickLoaderStats stats() const;

 private:
  struct Queued {
    float priority;
    uint64_t sequence;  // request order, so equal priorities are first in, first out
    int64_t id;
    bool operator<(const Queued& o) const {
      if (priority != o.priority) return priority > o.priority;
      return sequence < o.sequence;
    }
  };
  struct Outcome;

  void workerLoop();
  Outcome load(int64_t id) const;
  void finish(int64_t id, Outcome outcome, std::unique_lock<std::mutex>& lock);
  bool requestLocked(int64_t id, float priority);
  void dequeueLocked(int64_t id);
  bool idleLocked() const;

  const StoreReader& store_;
  BrickCache& cache_;
  BrickLoaderOptions options_;

  mutable std::mutex mutex_;
  std::condition_variable workAvailable_;
  std::condition_variable becameIdle_;
  std::set<Queued> queue_;  // best first
  std::unordered_map<int64_t, std::set<Queued>::iterator> queuedById_;
  std::unordered_map<int64_t, bool> loading_;  // id -> cancelled
  std::vector<int64_t> completed_;
  std::vector<LoadError> errors_;
  uint64_t nextSequence_ = 0;
  int callbacksRunning_ = 0;
  bool paused_ = false;
  bool stopping_ = false;
  BrickLoaderStats stats_;
  std::vector<std::thread> workers_;  // last: started after every member above exists
};

}  // namespace octoray::volume
