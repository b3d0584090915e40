// The web server's connection book (see web_limits.hpp).
#include "web_limits.hpp"

#include <algorithm>
#include <utility>
#include <vector>

namespace depthfuse::monitor {

ConnectionTable::Admission ConnectionTable::admit(uint64_t id, const std::string& address,
                                                  Clock::time_point now, const EvictableFn& evictable) {
  Admission a;
  const auto it = per_address_.find(address);
  const bool address_full = it != per_address_.end() &&
                            it->second.connections >= limits_.max_connections_per_address;
  if (address_full || entries_.size() >= limits_.max_connections) {
    // Room is made in the address's own share when that is what is full.
    a.evict = longest_waiting(address_full ? &address : nullptr, evictable);
    if (a.evict == 0) return a;
    remove(a.evict);
  }
  entries_[id] = Entry{address, State::kWaiting, now};
  ++per_address_[address].connections;
  a.admitted = true;
  return a;
}

uint64_t ConnectionTable::longest_waiting(const std::string* address, const EvictableFn& evictable) const {
  std::vector<std::pair<Clock::time_point, uint64_t>> waiting;
  for (const auto& [id, e] : entries_)
    if (e.state == State::kWaiting && (!address || e.address == *address)) waiting.emplace_back(e.since, id);
  std::sort(waiting.begin(), waiting.end());
  for (const auto& [since, id] : waiting)
    if (evictable(id)) return id;
  return 0;
}

void ConnectionTable::waiting(uint64_t id, Clock::time_point since) {
  const auto it = entries_.find(id);
  if (it == entries_.end() || it->second.state == State::kPage) return;
  it->second.state = State::kWaiting;
  it->second.since = since;
}

void ConnectionTable::busy(uint64_t id) {
  const auto it = entries_.find(id);
  if (it != entries_.end() && it->second.state != State::kPage) it->second.state = State::kBusy;
}

bool ConnectionTable::make_page(uint64_t id) {
  const auto it = entries_.find(id);
  if (it == entries_.end()) return false;
  if (it->second.state == State::kPage) return true;
  PerAddress& a = per_address_[it->second.address];
  if (pages_ >= limits_.max_pages || a.pages >= limits_.max_pages_per_address) return false;
  it->second.state = State::kPage;
  ++a.pages;
  ++pages_;
  return true;
}

void ConnectionTable::remove(uint64_t id) {
  const auto it = entries_.find(id);
  if (it == entries_.end()) return;
  const auto a = per_address_.find(it->second.address);
  if (it->second.state == State::kPage) {
    --a->second.pages;
    --pages_;
  }
  if (--a->second.connections == 0) per_address_.erase(a);
  entries_.erase(it);
}

}  // namespace depthfuse::monitor
