# Hardens the C++ decoders lcm-gen 1.3.1 writes, so that a corrupt or hostile message is rejected
# instead of exhausting memory or throwing:
#  - a variable-length array is resized to its length field *before* the length is checked against
#    the bytes left, so a length of 2^31 allocates (and zeroes) gigabytes: every element takes at
#    least one byte on the wire, so a length above the bytes left is rejected first;
#  - a string length of 0 or below makes std::string::assign throw: rejected too.
# And makes the message constants (PROTOCOL_VERSION, STATE_*, ...) `static constexpr`, which is
# inline in C++17: lcm-gen's `static const` members have no definition, so binding one to a
# reference (std::max, EXPECT_EQ) fails to link.
# Usage: cmake -DHEADERS="a.hpp;b.hpp" -P harden_generated.cmake
foreach(_hdr ${HEADERS})
  file(READ ${_hdr} _text)
  set(_orig "${_text}")
  # if(this->n) {\n        this->data.resize(this->n);   and   this->kv.resize(this->nkv);
  string(REGEX REPLACE
    "([ ]*)this->([A-Za-z0-9_]+)\\.resize\\(this->([A-Za-z0-9_]+)\\);"
    "\\1if(this->\\3 < 0 || this->\\3 > maxlen - pos) return -1; /* depthfuse: harden_generated.cmake */\n\\1this->\\2.resize(this->\\3);"
    _text "${_text}")
  string(REGEX REPLACE
    "if\\((__[A-Za-z0-9_]+_len__) > maxlen - pos\\) return -1;"
    "if(\\1 < 1 || \\1 > maxlen - pos) return -1; /* depthfuse: harden_generated.cmake */"
    _text "${_text}")
  string(REGEX REPLACE "static const (u?int[0-9]+_t|double|float|int8_t) "
    "static constexpr \\1 " _text "${_text}")
  if(_text MATCHES "_decodeNoHash" AND _text MATCHES "\\.resize\\(" AND NOT _text MATCHES "harden_generated")
    message(FATAL_ERROR "harden_generated.cmake: ${_hdr} has arrays but no decoder was hardened; "
                        "lcm-gen's output changed: update the patterns")
  endif()
  if(NOT _text STREQUAL _orig)
    file(WRITE ${_hdr} "${_text}")
  endif()
endforeach()
