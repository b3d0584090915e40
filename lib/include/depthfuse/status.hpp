// Errors as return values: every fallible call in depthfuse returns a Status or a Result<T>.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <variant>

namespace depthfuse {

enum class StatusCode {
  kOk = 0,
  kInvalidArgument,  // bad input: a garbage config value, a malformed file, a wrong image size
  kNotFound,         // a missing file, a frame with no pose
  kIoError,          // the OS refused: read/write failed, disk full
  kCorrupt,          // data that fails its own checks: damaged PNG, truncated message, bad checkpoint
  kUnsupported,      // a feature not built in (e.g. the kinect2 source without libfreenect2)
  kEndOfStream,      // a frame source has no more frames
  kUnavailable,      // a device or transport that is not there right now (retry may help)
  kInternal,
};

const char* to_string(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}
  static Status ok() { return {}; }

  bool is_ok() const { return code_ == StatusCode::kOk; }
  explicit operator bool() const { return is_ok(); }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }
  // "invalid argument: <message>"
  std::string to_string() const;
  // Prepends context: Status("x").with_context("reading a.png") -> "reading a.png: x".
  Status with_context(const std::string& context) const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

inline Status invalid_argument(std::string m) { return {StatusCode::kInvalidArgument, std::move(m)}; }
inline Status not_found(std::string m) { return {StatusCode::kNotFound, std::move(m)}; }
inline Status io_error(std::string m) { return {StatusCode::kIoError, std::move(m)}; }
inline Status corrupt(std::string m) { return {StatusCode::kCorrupt, std::move(m)}; }
inline Status unsupported(std::string m) { return {StatusCode::kUnsupported, std::move(m)}; }
inline Status end_of_stream() { return {StatusCode::kEndOfStream, "end of stream"}; }
inline Status unavailable(std::string m) { return {StatusCode::kUnavailable, std::move(m)}; }
inline Status internal_error(std::string m) { return {StatusCode::kInternal, std::move(m)}; }

// A value or the Status that explains why there is none.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}           // NOLINT: implicit by design
  Result(Status status) : v_(std::move(status)) {}    // NOLINT: must not be ok()

  bool is_ok() const { return std::holds_alternative<T>(v_); }
  explicit operator bool() const { return is_ok(); }
  const Status& status() const {
    static const Status kOk;
    return is_ok() ? kOk : std::get<Status>(v_);
  }
  T& value() & { return std::get<T>(v_); }
  const T& value() const& { return std::get<T>(v_); }
  T&& value() && { return std::get<T>(std::move(v_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

 private:
  std::variant<T, Status> v_;
};

}  // namespace depthfuse

#define DF_RETURN_IF_ERROR(expr)                 \
  do {                                           \
    ::depthfuse::Status _df_st = (expr);         \
    if (!_df_st.is_ok()) return _df_st;          \
  } while (0)
