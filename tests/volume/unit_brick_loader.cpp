// The asynchronous brick loader: priority order (ties first in, first out), re-prioritisation,
// cancellation of queued and in-progress loads, per-node error reporting for a corrupted
// brick, and a destructor that returns promptly with work pending.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <numeric>
#include <random>
#include <thread>

#include "memory_volume.h"
#include "octoray/volume/brick_loader.h"
#include "octoray/volume/store_builder.h"
#include "file_damage.h"
#include "test_paths.h"

namespace octoray::volume {
namespace {

using namespace std::chrono_literals;
using Ids = std::vector<int64_t>;

constexpr uint64_t kLargeBudgetBytes = uint64_t{1} << 30;

// 64^3 noise in 16^3 bricks: 64 leaves + 8 + 1 = 73 nodes, none constant.
class BrickLoaderTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    test::MemoryVolume volume({64, 64, 64}, [](int64_t i, int64_t j, int64_t k) {
      const uint64_t h = static_cast<uint64_t>(i * 73856093 ^ j * 19349663 ^ k * 83492791);
      return static_cast<float>(h % 3000) - 1000.0f;
    });
    dir_ = new std::filesystem::path(test::freshTempDir("brick_loader"));
    path_ = new std::string((*dir_ / "noise.octoray").string());
    BuildOptions options;
    options.brickSize = 16;
    buildStore(volume, *path_, options);
  }
  static void TearDownTestSuite() {
    delete path_;
    delete dir_;
  }
  void SetUp() override { store_ = std::make_unique<StoreReader>(*path_); }

  int64_t nodeCount() const { return static_cast<int64_t>(store_->nodes().size()); }
  Ids allIds() const {
    Ids ids(static_cast<std::size_t>(nodeCount()));
    std::iota(ids.begin(), ids.end(), int64_t{0});
    return ids;
  }

  static std::filesystem::path* dir_;
  static std::string* path_;
  std::unique_ptr<StoreReader> store_;
};
std::filesystem::path* BrickLoaderTest::dir_ = nullptr;
std::string* BrickLoaderTest::path_ = nullptr;

BrickLoaderOptions loaderOptions(int threads, bool startPaused = false) {
  BrickLoaderOptions options;
  options.threads = threads;
  options.startPaused = startPaused;
  return options;
}

// Holds the worker inside beforeLoad for one id until released, and tells when it got there.
class LoadGate {
 public:
  explicit LoadGate(int64_t id) : id_(id) {}
  void atLoad(int64_t id) {
    if (id != id_) return;
    std::unique_lock lock(mutex_);
    reached_ = true;
    changed_.notify_all();
    changed_.wait(lock, [this] { return released_; });
  }
  bool waitReached() {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, 10s, [this] { return reached_; });
  }
  void release() {
    const std::lock_guard lock(mutex_);
    released_ = true;
    changed_.notify_all();
  }

 private:
  int64_t id_;
  std::mutex mutex_;
  std::condition_variable changed_;
  bool reached_ = false, released_ = false;
};

TEST_F(BrickLoaderTest, StoreHasManyNonConstantBricks) {
  ASSERT_EQ(nodeCount(), 73);
  for (const NodeRecord& n : store_->nodes()) EXPECT_GT(n.payloadBytes, 0u);
}

TEST_F(BrickLoaderTest, LoadsHighestPriorityFirstAndTiesInRequestOrder) {
  BrickCache cache(kLargeBudgetBytes);
  BrickLoader loader(*store_, cache, loaderOptions(1, true));
  // Requested in a shuffled order with five priority classes, so ties are common.
  Ids order = allIds();
  std::shuffle(order.begin(), order.end(), std::mt19937(3));
  std::vector<std::pair<float, std::size_t>> keys;  // (priority, request position)
  for (std::size_t n = 0; n < order.size(); ++n) {
    const auto priority = static_cast<float>(order[n] % 5);
    EXPECT_TRUE(loader.request(order[n], priority));
    keys.emplace_back(priority, n);
  }
  std::vector<std::size_t> positions(order.size());
  std::iota(positions.begin(), positions.end(), std::size_t{0});
  std::stable_sort(positions.begin(), positions.end(),
                   [&](std::size_t a, std::size_t b) { return keys[a].first > keys[b].first; });
  Ids expected;
  for (std::size_t p : positions) expected.push_back(order[p]);

  EXPECT_EQ(loader.stats().queued, order.size());
  EXPECT_TRUE(loader.poll().empty());  // paused: nothing loads
  loader.resume();
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_EQ(loader.poll(), expected);
  EXPECT_TRUE(loader.takeErrors().empty());
  for (int64_t id : order) {
    const auto brick = cache.find(id);
    ASSERT_NE(brick, nullptr) << id;
    EXPECT_EQ(brick->nodeId, id);
  }
  EXPECT_EQ(loader.stats().loaded, order.size());
}

TEST_F(BrickLoaderTest, ReRequestChangesPriorityAndSameRequestKeepsPlace) {
  BrickCache cache(kLargeBudgetBytes);
  BrickLoader loader(*store_, cache, loaderOptions(1, true));
  for (int64_t id = 0; id < 10; ++id) loader.request(id, 1.0f);
  EXPECT_TRUE(loader.request(7, 5.0f));  // raised: first
  EXPECT_TRUE(loader.request(3, 2.0f));  // raised: second
  EXPECT_TRUE(loader.request(0, 1.0f));  // unchanged: keeps its place at the front of the ties
  EXPECT_TRUE(loader.request(1, 0.5f));  // lowered: last
  EXPECT_TRUE(loader.request(4, 2.0f));  // raised after 3: ties with 3, behind it
  EXPECT_EQ(loader.stats().queued, 10u);
  loader.resume();
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_EQ(loader.poll(), (Ids{7, 3, 4, 0, 2, 5, 6, 8, 9, 1}));
}

TEST_F(BrickLoaderTest, SetRequestsReplacesTheFramesQueue) {
  BrickCache cache(kLargeBudgetBytes);
  BrickLoader loader(*store_, cache, loaderOptions(1, true));
  for (int64_t id = 0; id < 6; ++id) loader.request(id, 1.0f);
  // Next frame: 0..2 no longer wanted, 4 more urgent, 10 new.
  const std::vector<LoadRequest> frame{{3, 1.0f}, {4, 9.0f}, {5, 1.0f}, {10, 1.0f}};
  loader.setRequests(frame);
  EXPECT_FALSE(loader.isQueued(0));
  EXPECT_TRUE(loader.isQueued(10));
  loader.resume();
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_EQ(loader.poll(), (Ids{4, 3, 5, 10}));
  EXPECT_FALSE(cache.contains(0));

  const std::vector<LoadRequest> bad{{1, 1.0f}, {nodeCount(), 1.0f}};
  loader.pause();
  EXPECT_THROW(loader.setRequests(bad), std::out_of_range);
  EXPECT_FALSE(loader.isQueued(1));  // a rejected frame changes nothing
}

TEST_F(BrickLoaderTest, CachedIdIsNoOpAndBadIdThrows) {
  BrickCache cache(kLargeBudgetBytes);
  cache.insert(std::make_shared<const Brick>(store_->readBrick(5)));
  BrickLoader loader(*store_, cache, loaderOptions(1, true));
  EXPECT_FALSE(loader.request(5, 1.0f));
  EXPECT_FALSE(loader.isQueued(5));
  EXPECT_THROW(loader.request(-1, 1.0f), std::out_of_range);
  EXPECT_THROW(loader.request(nodeCount(), 1.0f), std::out_of_range);
  EXPECT_THROW(BrickLoader(*store_, cache, loaderOptions(0)), std::invalid_argument);
}

TEST_F(BrickLoaderTest, NanPriorityLoadsLast) {
  BrickCache cache(kLargeBudgetBytes);
  BrickLoader loader(*store_, cache, loaderOptions(1, true));
  loader.request(1, std::numeric_limits<float>::quiet_NaN());
  loader.request(2, -1e30f);
  loader.request(3, 0.0f);
  loader.resume();
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_EQ(loader.poll(), (Ids{3, 2, 1}));
}

TEST_F(BrickLoaderTest, CancelledQueuedIdsNeverArrive) {
  BrickCache cache(kLargeBudgetBytes);
  std::mutex seenMutex;
  Ids seenByCallback;
  BrickLoaderOptions options = loaderOptions(2, true);
  options.onLoaded = [&](int64_t id) {
    const std::lock_guard lock(seenMutex);
    seenByCallback.push_back(id);
  };
  BrickLoader loader(*store_, cache, options);
  for (int64_t id : allIds()) loader.request(id, static_cast<float>(id));
  for (int64_t id = 0; id < nodeCount(); id += 2) EXPECT_TRUE(loader.cancel(id));
  EXPECT_FALSE(loader.cancel(0));  // already gone
  loader.resume();
  ASSERT_TRUE(loader.waitIdle(30s));
  Ids got = loader.poll();
  std::sort(got.begin(), got.end());
  std::sort(seenByCallback.begin(), seenByCallback.end());
  Ids odd;
  for (int64_t id = 1; id < nodeCount(); id += 2) odd.push_back(id);
  EXPECT_EQ(got, odd);
  EXPECT_EQ(seenByCallback, odd);
  for (int64_t id = 0; id < nodeCount(); id += 2) EXPECT_FALSE(cache.contains(id)) << id;

  loader.pause();
  for (int64_t id : {0, 2, 4}) loader.request(id, 1.0f);
  loader.cancelAll();
  loader.resume();
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_TRUE(loader.poll().empty());
}

TEST_F(BrickLoaderTest, CancelDuringLoadDiscardsTheBrick) {
  BrickCache cache(kLargeBudgetBytes);
  LoadGate gate(9);
  BrickLoaderOptions options = loaderOptions(1);
  options.beforeLoad = [&](int64_t id) { gate.atLoad(id); };
  BrickLoader loader(*store_, cache, options);
  loader.request(9, 1.0f);
  ASSERT_TRUE(gate.waitReached());
  EXPECT_EQ(loader.stats().loading, 1u);
  EXPECT_TRUE(loader.cancel(9));
  EXPECT_FALSE(loader.cancel(9));
  gate.release();
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_TRUE(loader.poll().empty());
  EXPECT_FALSE(cache.contains(9));
  EXPECT_EQ(loader.stats().loaded, 0u);
}

TEST_F(BrickLoaderTest, IdBeingLoadedIsNotLoadedTwice) {
  BrickCache cache(kLargeBudgetBytes);
  LoadGate gate(9);
  std::atomic<int> reads{0};
  BrickLoaderOptions options = loaderOptions(2);
  options.beforeLoad = [&](int64_t id) {
    if (id == 9) ++reads;
    gate.atLoad(id);
  };
  BrickLoader loader(*store_, cache, options);
  loader.request(9, 1.0f);
  ASSERT_TRUE(gate.waitReached());
  EXPECT_FALSE(loader.request(9, 5.0f));  // in progress: not queued again
  EXPECT_FALSE(loader.isQueued(9));
  loader.cancel(9);
  EXPECT_FALSE(loader.request(9, 1.0f));  // wanted again while in progress: revives that load
  gate.release();
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_EQ(loader.poll(), (Ids{9}));
  EXPECT_EQ(reads.load(), 1);
  EXPECT_TRUE(cache.contains(9));
}

TEST_F(BrickLoaderTest, CorruptedBrickIsReportedForItsIdAndOthersLoad) {
  // Flip one byte in the middle of node 20's compressed payload.
  const std::filesystem::path corrupt = test::freshTempDir("brick_loader_corrupt") / "bad.octoray";
  std::filesystem::copy_file(*path_, corrupt);
  constexpr int64_t kBad = 20;
  const NodeRecord& bad = store_->node(kBad);
  test::flipByte(corrupt, static_cast<std::streamoff>(bad.payloadOffset + bad.payloadBytes / 2));
  if (HasFatalFailure()) return;
  const StoreReader store(corrupt.string());  // header and node table are intact
  BrickCache cache(kLargeBudgetBytes);
  std::mutex errorsMutex;
  std::vector<LoadError> errorsByCallback;
  BrickLoaderOptions options = loaderOptions(2);
  options.onError = [&](const LoadError& e) {
    const std::lock_guard lock(errorsMutex);
    errorsByCallback.push_back(e);
  };
  BrickLoader loader(store, cache, options);
  for (int64_t id : allIds()) loader.request(id, 1.0f);
  ASSERT_TRUE(loader.waitIdle(30s));

  const std::vector<LoadError> errors = loader.takeErrors();
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_EQ(errors[0].id, kBad);
  EXPECT_NE(errors[0].message.find("checksum"), std::string::npos) << errors[0].message;
  EXPECT_NE(errors[0].message.find(corrupt.string()), std::string::npos) << errors[0].message;
  ASSERT_EQ(errorsByCallback.size(), 1u);
  EXPECT_EQ(errorsByCallback[0].id, kBad);
  EXPECT_TRUE(loader.takeErrors().empty());

  Ids got = loader.poll();
  std::sort(got.begin(), got.end());
  Ids expected = allIds();
  expected.erase(expected.begin() + kBad);
  EXPECT_EQ(got, expected);
  EXPECT_FALSE(cache.contains(kBad));
  EXPECT_EQ(loader.stats().failed, 1u);
}

TEST_F(BrickLoaderTest, BrickOverCacheBudgetIsAnErrorNotALoop) {
  BrickCache cache(1024);  // far below one 18^3 brick
  BrickLoader loader(*store_, cache, loaderOptions(1));
  loader.request(0, 1.0f);
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_TRUE(loader.poll().empty());
  const auto errors = loader.takeErrors();
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_NE(errors[0].message.find("cache budget"), std::string::npos) << errors[0].message;
}

TEST_F(BrickLoaderTest, ThrowingCallbackIsReportedNotFatal) {
  BrickCache cache(kLargeBudgetBytes);
  BrickLoaderOptions options = loaderOptions(1);
  options.onLoaded = [](int64_t id) {
    if (id == 2) throw std::runtime_error("viewer went away");
  };
  BrickLoader loader(*store_, cache, options);
  for (int64_t id : {1, 2, 3}) loader.request(id, static_cast<float>(-id));
  ASSERT_TRUE(loader.waitIdle(30s));
  EXPECT_EQ(loader.poll(), (Ids{1, 2, 3}));
  const auto errors = loader.takeErrors();
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_EQ(errors[0].id, 2);
  EXPECT_NE(errors[0].message.find("viewer went away"), std::string::npos);
}

TEST_F(BrickLoaderTest, DestructorWithPendingRequestsReturnsPromptly) {
  BrickCache cache(kLargeBudgetBytes);
  const auto start = std::chrono::steady_clock::now();
  {
    BrickLoader paused(*store_, cache, loaderOptions(2, true));
    for (int64_t id : allIds()) paused.request(id, 1.0f);
  }
  for (int round = 0; round < 20; ++round) {
    cache.clear();
    BrickLoader running(*store_, cache, loaderOptions(3));
    for (int64_t id : allIds()) running.request(id, static_cast<float>(id % 7));
  }
  {
    // A load held in progress is discarded when the loader goes away during it.
    LoadGate gate(4);
    std::atomic<int> loaded{0};
    BrickLoaderOptions options = loaderOptions(1);
    options.beforeLoad = [&](int64_t id) { gate.atLoad(id); };
    options.onLoaded = [&](int64_t) { ++loaded; };
    cache.clear();
    auto loader = std::make_unique<BrickLoader>(*store_, cache, options);
    loader->request(4, 1.0f);
    ASSERT_TRUE(gate.waitReached());
    std::thread release([&] {
      std::this_thread::sleep_for(50ms);
      gate.release();
    });
    loader.reset();
    release.join();
    EXPECT_EQ(loaded.load(), 0);
    EXPECT_FALSE(cache.contains(4));
  }
  EXPECT_LT(std::chrono::steady_clock::now() - start, 20s);
}

// Several client threads request, re-prioritise, cancel and poll while three workers load
// into a cache that holds a fraction of the store (run under the sanitizers too).
TEST_F(BrickLoaderTest, ConcurrentClientsAndWorkersStayConsistent) {
  BrickCache cache(16 * store_->readBrick(0).byteSize());
  BrickLoader loader(*store_, cache, loaderOptions(3));
  std::atomic<int> outOfRange{0};
  std::vector<std::thread> clients;
  for (int t = 0; t < 4; ++t) {
    clients.emplace_back([&, t] {
      std::mt19937 rng(static_cast<unsigned>(100 + t));
      std::uniform_int_distribution<int64_t> pick(0, nodeCount() - 1);
      std::uniform_real_distribution<float> priority(0.0f, 10.0f);
      for (int op = 0; op < 400; ++op) {
        const int64_t id = pick(rng);
        switch (op % 8) {
          case 0:
            loader.cancel(id);
            break;
          case 1: {
            std::vector<LoadRequest> frame;
            for (int n = 0; n < 10; ++n) frame.push_back({pick(rng), priority(rng)});
            loader.setRequests(frame);
            break;
          }
          case 2:
            for (int64_t done : loader.poll()) {
              if (done < 0 || done >= nodeCount()) ++outOfRange;
            }
            break;
          case 3:
            if (const auto b = cache.find(id); b && b->nodeId != id) ++outOfRange;
            break;
          default:
            loader.request(id, priority(rng));
            break;
        }
      }
    });
  }
  for (std::thread& c : clients) c.join();
  ASSERT_TRUE(loader.waitIdle(60s));
  EXPECT_EQ(outOfRange.load(), 0);
  EXPECT_TRUE(loader.takeErrors().empty());
  const BrickLoaderStats s = loader.stats();
  EXPECT_EQ(s.queued, 0u);
  EXPECT_EQ(s.loading, 0u);
  EXPECT_GT(s.loaded, 0u);
  EXPECT_LE(cache.stats().bytes, cache.budgetBytes());
}

}  // namespace
}  // namespace octoray::volume
