// The rig key and message signatures (see message_auth.hpp), on libsodium: Debian's well-kept
// implementation of HMAC-SHA-512-256 and of constant-time comparison, rather than our own.
#include "depthfuse/lcm/message_auth.hpp"

#include <sodium.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cstring>

#include "depthfuse/input_file.hpp"

namespace depthfuse::lcm {

namespace {

// libsodium must be initialised once before use; sodium_init() is thread-safe and idempotent.
void init_sodium() {
  static const int rc = sodium_init();
  (void)rc;  // < 0 only when no randomness source exists, which signing does not use
}

// Keys in the replay cache: a tag's first 8 bytes, which do not collide among honest messages.
uint64_t tag_key(const uint8_t* tag) {
  uint64_t k = 0;
  std::memcpy(&k, tag, sizeof k);
  return k;
}

void put_be32(uint32_t v, uint8_t* out) {
  for (int i = 0; i < 4; ++i) out[i] = static_cast<uint8_t>(v >> (24 - 8 * i));
}
void put_be64(int64_t v, uint8_t* out) {
  const auto u = static_cast<uint64_t>(v);
  for (int i = 0; i < 8; ++i) out[i] = static_cast<uint8_t>(u >> (56 - 8 * i));
}
uint32_t get_be32(const uint8_t* in) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v = (v << 8) | in[i];
  return v;
}
int64_t get_be64(const uint8_t* in) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | in[i];
  return static_cast<int64_t>(v);
}

// The cache only has to hold what honest senders sign within its window (a few hundred messages
// a second); past this, the oldest entries go first.
constexpr size_t kMaxRecentTags = size_t{1} << 16;

}  // namespace

std::string RigKey::how_to_make(const std::string& path) {
  return "(umask 027; od -An -tx1 -N32 /dev/urandom | tr -d ' \\n' > " + path +
         ") && chgrp depthfuse " + path;
}

Result<RigKey> RigKey::load(const std::string& path) {
  auto file = InputFile::open(path, "rig key");
  if (!file) {
    if (file.status().code() != StatusCode::kNotFound) return file.status();
    return not_found(file.status().message() + "; make one with: " + how_to_make(path));
  }
  // Anyone who can read the key can command the rig, and anyone who can change it can lock the
  // rig's own programs out: like ssh with a private key, a key file that others may read or
  // write is refused. Its group (the daemons') may read it.
  const mode_t mode = file->info().st_mode;
  const char* loose = (mode & S_IROTH)   ? "readable by every user"
                      : (mode & S_IWOTH) ? "writable by every user"
                      : (mode & S_IWGRP) ? "writable by its group"
                                         : nullptr;
  if (loose != nullptr)
    return invalid_argument("rig key " + path + " is " + loose + "; restrict it with 'chmod 640 " +
                            path + "'");
  // A key file is 64 digits and a newline: anything much longer is not one.
  auto text = file->read_all(256);
  if (!text) return text.status();

  std::string hex;
  for (char c : *text)
    if (!std::isspace(static_cast<unsigned char>(c))) hex.push_back(c);
  RigKey key;
  size_t bin_len = 0;
  if (hex.size() != 2 * kRigKeyBytes ||
      sodium_hex2bin(key.bytes_.data(), key.bytes_.size(), hex.data(), hex.size(), nullptr,
                     &bin_len, nullptr) != 0 ||
      bin_len != kRigKeyBytes)
    return invalid_argument("rig key " + path + ": expected " + std::to_string(2 * kRigKeyBytes) +
                            " hexadecimal digits (make one with: " + how_to_make(path) + ")");
  // A key of one byte repeated (all zeros: a placeholder, an image's blank) is guessed at once.
  if (std::all_of(key.bytes_.begin(), key.bytes_.end(),
                  [&](uint8_t b) { return b == key.bytes_[0]; }))
    return invalid_argument("rig key " + path + " is one byte repeated (" + hex.substr(0, 2) +
                            "), no secret: make a new one with: " + how_to_make(path));
  return key;
}

RigKey RigKey::from_bytes(const std::array<uint8_t, kRigKeyBytes>& bytes) {
  RigKey key;
  key.bytes_ = bytes;
  return key;
}

std::string RigKey::fingerprint() const {
  init_sodium();
  // A hash with its own context string, so that the fingerprint says nothing usable about the key.
  static const char kContext[] = "depthfuse rig key fingerprint";
  uint8_t hash[8];
  crypto_generichash(hash, sizeof hash, reinterpret_cast<const uint8_t*>(kContext),
                     sizeof kContext - 1, bytes_.data(), bytes_.size());
  char hex[2 * sizeof hash + 1];
  sodium_bin2hex(hex, sizeof hex, hash, sizeof hash);
  return hex;
}

const char* to_string(AuthDrop reason) {
  switch (reason) {
    case AuthDrop::kUnsigned: return "unsigned";
    case AuthDrop::kBadSignature: return "bad_signature";
    case AuthDrop::kStale: return "stale";
    case AuthDrop::kReplayed: return "replayed";
    case AuthDrop::kCount: break;
  }
  return "?";
}

uint64_t AuthCounters::dropped_total() const {
  uint64_t n = 0;
  for (uint64_t d : dropped) n += d;
  return n;
}

MessageAuth::MessageAuth(const RigKey& key, int64_t max_skew_us)
    : key_(key.bytes()), max_skew_us_(max_skew_us) {
  init_sodium();
}

void MessageAuth::tag(std::string_view channel, const uint8_t* payload, size_t size,
                      const uint8_t* header, uint8_t* out) const {
  crypto_auth_hmacsha512256_state state;
  crypto_auth_hmacsha512256_init(&state, key_.data(), key_.size());
  crypto_auth_hmacsha512256_update(&state, reinterpret_cast<const uint8_t*>(channel.data()),
                                   channel.size());
  const uint8_t nul = 0;
  crypto_auth_hmacsha512256_update(&state, &nul, 1);
  crypto_auth_hmacsha512256_update(&state, payload, size);
  crypto_auth_hmacsha512256_update(&state, header, 12);
  crypto_auth_hmacsha512256_final(&state, out);
}

void MessageAuth::sign(std::string_view channel, const uint8_t* payload, size_t size,
                       int64_t utime, uint8_t* trailer) const {
  put_be32(kSignatureMagic, trailer);
  put_be64(utime, trailer + 4);
  tag(channel, payload, size, trailer, trailer + 12);
}

MessageAuth::Verdict MessageAuth::verify(std::string_view channel, const uint8_t* data,
                                         size_t size, int64_t now_utime) {
  Verdict v;
  auto drop = [&](AuthDrop reason) {
    ++counters_.dropped[static_cast<size_t>(reason)];
    v.reason = reason;
    return v;
  };
  if (size < kSignatureBytes) return drop(AuthDrop::kUnsigned);
  const uint8_t* trailer = data + size - kSignatureBytes;
  if (get_be32(trailer) != kSignatureMagic) return drop(AuthDrop::kUnsigned);
  const size_t payload_size = size - kSignatureBytes;
  uint8_t expected[kSignatureTagBytes];
  tag(channel, data, payload_size, trailer, expected);
  if (sodium_memcmp(expected, trailer + 12, kSignatureTagBytes) != 0)
    return drop(AuthDrop::kBadSignature);
  // Only a signed time is trusted, so the time is checked after the tag.
  const int64_t utime = get_be64(trailer + 4);
  if (utime < now_utime - max_skew_us_ || utime > now_utime + max_skew_us_)
    return drop(AuthDrop::kStale);
  if (seen_before(trailer + 12, now_utime)) return drop(AuthDrop::kReplayed);
  ++counters_.verified;
  v.ok = true;
  v.payload_size = payload_size;
  return v;
}

bool MessageAuth::seen_before(const uint8_t* tag, int64_t now_utime) {
  // A message that arrived more than 2 * max_skew ago carried a time older than now - max_skew,
  // so a replay of it is stale: its tag can be forgotten.
  const int64_t forget_before = now_utime - 2 * max_skew_us_;
  while (!recent_order_.empty() &&
         (recent_order_.front().first < forget_before || recent_order_.size() >= kMaxRecentTags)) {
    recent_.erase(recent_order_.front().second);
    recent_order_.pop_front();
  }
  const uint64_t key = tag_key(tag);
  if (!recent_.insert(key).second) return true;
  recent_order_.emplace_back(now_utime, key);
  return false;
}

size_t unsigned_payload_size(const uint8_t* data, size_t size) {
  if (data == nullptr || size < kSignatureBytes) return size;
  if (get_be32(data + size - kSignatureBytes) != kSignatureMagic) return size;
  return size - kSignatureBytes;
}

}  // namespace depthfuse::lcm
