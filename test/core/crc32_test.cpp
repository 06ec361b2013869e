#include "nerfslam/core/crc32.h"

#include <gtest/gtest.h>

#include <string>

namespace nerfslam {
namespace {

TEST(Crc32, MatchesZlibCheckValue) {
  // The standard check value of CRC-32/ISO-HDLC (zlib's crc32, PNG).
  EXPECT_EQ(crc32("123456789", 9), 0xCBF43926u);
  EXPECT_EQ(crc32(std::string("123456789")), 0xCBF43926u);
  EXPECT_EQ(crc32("", 0), 0u);
}

TEST(Crc32, IncrementalEqualsOneShot) {
  EXPECT_EQ(crc32("56789", 5, crc32("1234", 4)), 0xCBF43926u);
  EXPECT_EQ(crc32(std::string("56789"), crc32(std::string("1234"))), 0xCBF43926u);
}

}  // namespace
}  // namespace nerfslam
