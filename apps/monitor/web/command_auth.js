// The operator token on the page's commands (apps/monitor/page_auth.hpp, docs/operator-view.md):
// the page signs each command's body with the rig key as depthfuse signs its LCM messages,
//   signature = "DFS1" | utime (int64 big-endian, µs, the monitor's clock) | tag
//   tag = HMAC-SHA-512-256(key, channel | NUL | body | "DFS1" | utime)   (libsodium's crypto_auth)
// and sends it in hex in the X-Depthfuse-Signature header; the key stays in the browser.
// HMAC (RFC 2104) is formed here over TweetNaCl's SHA-512 (nacl.hash, Debian's node-tweetnacl) and
// truncated to 32 bytes, which is what crypto_auth_hmacsha512256 computes: browsers offer
// crypto.subtle only to https and localhost pages, and this page is also served over plain HTTP.
'use strict';

const dfCommandAuth = (() => {
  const kBlockBytes = 128;  // SHA-512's block
  const kKeyBytes = 32, kTagBytes = 32, kHeaderBytes = 12;
  const kMagic = [0x44, 0x46, 0x53, 0x31];  // "DFS1"

  // The rig key is shorter than a block, so it is used as it is, padded with zeros.
  function hmacSha512_256(key, message) {
    const inner = new Uint8Array(kBlockBytes + message.length);
    const outer = new Uint8Array(kBlockBytes + 64);
    for (let i = 0; i < kBlockBytes; ++i) {
      const k = i < key.length ? key[i] : 0;
      inner[i] = k ^ 0x36;
      outer[i] = k ^ 0x5c;
    }
    inner.set(message, kBlockBytes);
    outer.set(nacl.hash(inner), kBlockBytes);
    return nacl.hash(outer).subarray(0, kTagBytes);
  }

  // The key file's text (64 hexadecimal digits, whitespace around them allowed) as bytes, or null.
  function parseKey(text) {
    const hex = String(text).replace(/\s+/g, '');
    if (!/^[0-9a-fA-F]{64}$/.test(hex)) return null;
    const key = new Uint8Array(kKeyBytes);
    for (let i = 0; i < kKeyBytes; ++i) key[i] = parseInt(hex.substr(2 * i, 2), 16);
    return key;
  }

  function hex(bytes) {
    return Array.from(bytes, (b) => b.toString(16).padStart(2, '0')).join('');
  }

  // The X-Depthfuse-Signature header of `body` (a string, sent as UTF-8) on `channel` at `utime`
  // (µs on the monitor's clock, an integer).
  function sign(key, channel, body, utime) {
    const enc = new TextEncoder();
    const ch = enc.encode(channel), b = enc.encode(body);
    const signature = new Uint8Array(kHeaderBytes + kTagBytes);
    signature.set(kMagic, 0);
    const view = new DataView(signature.buffer);
    view.setUint32(4, Math.floor(utime / 2 ** 32));
    view.setUint32(8, utime % 2 ** 32);
    const message = new Uint8Array(ch.length + 1 + b.length + kHeaderBytes);
    message.set(ch, 0);
    message[ch.length] = 0;
    message.set(b, ch.length + 1);
    message.set(signature.subarray(0, kHeaderBytes), ch.length + 1 + b.length);
    signature.set(hmacSha512_256(key, message), kHeaderBytes);
    return hex(signature);
  }

  return {parseKey, sign, hex};
})();
