// pacs::sortForViewing: the order a retrieval fetches a series in, so that it arrives from one
// end of the stack to the other.
#include <gtest/gtest.h>

#include "octoray/pacs/query.h"

namespace octoray::pacs {
namespace {

InstanceRecord slice(const std::string& uid, int64_t number, std::optional<std::array<double, 3>> position,
                     std::array<double, 6> orientation = {1, 0, 0, 0, 1, 0}) {
  InstanceRecord r;
  r.sopInstanceUid = uid;
  r.instanceNumber = number;
  r.position = position;
  if (position) r.orientation = orientation;
  return r;
}

std::vector<std::string> uids(const std::vector<InstanceRecord>& instances) {
  std::vector<std::string> out;
  for (const auto& i : instances) out.push_back(i.sopInstanceUid);
  return out;
}

TEST(SortForViewing, AlongTheMajorityNormalThenTheRestByNumber) {
  // Axial slices listed out of order (numbers against position), a coronal localiser and an
  // instance without geometry: slices by z (the normal of rows x columns), then the others.
  std::vector<InstanceRecord> listed = {
      slice("z20", 1, std::array<double, 3>{0, 0, 20}), slice("loc", 9, std::array<double, 3>{0, 0, 0}, {1, 0, 0, 0, 0, -1}),
      slice("z-5", 2, std::array<double, 3>{3, 4, -5}), slice("none", 0, std::nullopt),
      slice("z7.5", 3, std::array<double, 3>{0, 2, 7.5})};
  sortForViewing(listed);
  EXPECT_EQ(uids(listed), (std::vector<std::string>{"z-5", "z7.5", "z20", "none", "loc"}));
  // A normal pointing the other way (rows x columns = -z) turns the order round.
  std::vector<InstanceRecord> flipped = {slice("a", 1, std::array<double, 3>{0, 0, 1}, {-1, 0, 0, 0, 1, 0}),
                                         slice("b", 2, std::array<double, 3>{0, 0, 2}, {-1, 0, 0, 0, 1, 0})};
  sortForViewing(flipped);
  EXPECT_EQ(uids(flipped), (std::vector<std::string>{"b", "a"}));
}

TEST(SortForViewing, WithoutPositionsByNumberKeepingTheServersOrderOnTies) {
  std::vector<InstanceRecord> listed = {slice("c", 2, std::nullopt), slice("b", -1, std::nullopt),
                                        slice("a", -1, std::nullopt), slice("d", 1, std::nullopt)};
  sortForViewing(listed);
  EXPECT_EQ(uids(listed), (std::vector<std::string>{"b", "a", "d", "c"}));
}

}  // namespace
}  // namespace octoray::pacs
