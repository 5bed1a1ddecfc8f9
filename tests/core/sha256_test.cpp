#include "flsh/core/sha256.h"

#include <gtest/gtest.h>

#include "flsh/core/error.h"
#include "flsh/core/types.h"

namespace flsh {
namespace {

// FIPS 180-2 appendix B test vectors.
TEST(Sha256, KnownVectors) {
  EXPECT_EQ(sha256Hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(sha256Hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(sha256Hex("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  EXPECT_EQ(sha256Hex(std::string(1000000, 'a')),
            "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

// Published XXH64 values (seed 0).
TEST(XxHash64, KnownVectors) {
  EXPECT_EQ(xxhash64("", 0), 0xEF46DB3751D8E999ULL);
  EXPECT_EQ(xxhash64("a", 1), 0xD24EC4F1A98C6E5BULL);
  const std::string text = "Nobody inspects the spammish repetition";
  EXPECT_EQ(xxhash64(text.data(), text.size()), 0xFBCEA83C8A378BF1ULL);
  // Every tail length (stripes of 32, then 8, 4 and single bytes) reacts to one changed byte.
  std::string bytes(100, 'q');
  for (size_t n = 0; n < bytes.size(); ++n) {
    const uint64_t before = xxhash64(bytes.data(), n + 1);
    bytes[n] ^= 1;
    EXPECT_NE(xxhash64(bytes.data(), n + 1), before) << n;
    bytes[n] ^= 1;
  }
}

// xxhash64(nullptr, 0) (an empty vector's data()) did pointer arithmetic on the null pointer
// (null + 0 and comparisons with it), undefined behaviour that UBSan reports as "applying zero
// offset to null pointer" (the sanitized suite aborts on it). It is now defined: the hash of the
// empty range, for every seed; and so are the Sha256 entry points that reach it.
TEST(XxHash64, NullPointerWithZeroBytesIsTheEmptyHash) {
  const uint8_t empty[1] = {0};
  EXPECT_EQ(xxhash64(nullptr, 0), 0xEF46DB3751D8E999ULL);
  EXPECT_EQ(xxhash64(nullptr, 0), xxhash64(empty, 0));
  for (uint64_t seed : {uint64_t(1), uint64_t(0x9E3779B185EBCA87ULL)})
    EXPECT_EQ(xxhash64(nullptr, 0, seed), xxhash64(empty, 0, seed)) << seed;
  Sha256 a, b;
  a.updateLarge("empty", nullptr, 0);
  b.updateLarge("empty", empty, 0);
  EXPECT_EQ(a.hexDigest(), b.hexDigest());
  Sha256 m, v;
  m.updateMatrix("m", MatX(0, 3));
  v.updateMatrix("m", MatX3(0, 3));
  EXPECT_EQ(m.hexDigest(), v.hexDigest());
}

TEST(Sha256, IncrementalEqualsOneShot) {
  std::string text;
  for (int i = 0; i < 1000; ++i) text += char('a' + i * 7 % 26);
  for (size_t split : {size_t(0), size_t(1), size_t(55), size_t(56), size_t(63), size_t(64),
                       size_t(65), size_t(999)}) {
    Sha256 h;
    h.update(text.substr(0, split));
    h.update(text.substr(split));
    EXPECT_EQ(h.hexDigest(), sha256Hex(text)) << "split at " << split;
  }
}

TEST(Sha256, FieldsAreDelimitedAndMatricesHashTheirValues) {
  Sha256 a, b;
  a.updateField("ab", "c", 1);
  b.updateField("a", "bc", 2);
  EXPECT_NE(a.hexDigest(), b.hexDigest());

  MatX3 row_major(2, 3);
  row_major << 1, 2, 3, 4, 5, 6;
  MatX col_major = row_major;
  Sha256 r, c, t;
  r.updateMatrix("m", row_major);
  c.updateMatrix("m", col_major);
  t.updateMatrix("m", col_major.transpose());
  const std::string digest = r.hexDigest();
  EXPECT_EQ(digest, c.hexDigest());
  EXPECT_NE(digest, t.hexDigest());  // shape is part of the digest
  EXPECT_THROW(r.update("more"), Error);
}

}  // namespace
}  // namespace flsh
