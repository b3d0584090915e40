#include "depthfuse/kinect2/depth_decoder.hpp"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>

#include "decode_kernels.hpp"
#include "decoder_tables.hpp"

namespace depthfuse::kinect2 {

namespace {

using Plane = std::vector<float>;

// A second thread that takes the lower half of the rows of each stage.
class HelperThread {
 public:
  HelperThread() : thread_([this] { loop(); }) {}
  ~HelperThread() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopping_ = true;
    }
    wake_.notify_one();
    thread_.join();
  }

  // Runs rows(first, mid) here and rows(mid, last) on the helper; returns when both are done.
  void split(int first, int last, const std::function<void(int, int)>& rows) {
    const int mid = (first + last) / 2;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      job_ = &rows;
      job_first_ = mid;
      job_last_ = last;
      done_ = false;
    }
    wake_.notify_one();
    rows(first, mid);
    std::unique_lock<std::mutex> lock(mutex_);
    finished_.wait(lock, [this] { return done_; });
    job_ = nullptr;
  }

 private:
  void loop() {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      wake_.wait(lock, [this] { return stopping_ || (job_ != nullptr && !done_); });
      if (stopping_) return;
      const auto* job = job_;
      const int first = job_first_, last = job_last_;
      lock.unlock();
      (*job)(first, last);
      lock.lock();
      done_ = true;
      finished_.notify_one();
    }
  }

  std::mutex mutex_;
  std::condition_variable wake_, finished_;
  const std::function<void(int, int)>* job_ = nullptr;
  int job_first_ = 0, job_last_ = 0;
  bool done_ = true;
  bool stopping_ = false;
  std::thread thread_;
};

// The bilateral filter's pairs of a row's pixels with the row below (kernels::pair_weights), per
// direction: 0 down-left (at the upper pixel's x), 1 down, 2 down-right (at x + 1); or with the
// right neighbour (slot 0, at x + 1). Shifted so that no pointer before a row is ever formed.
struct PairRow {
  std::array<Plane, 3> distance, weight;
  PairRow() {
    for (auto* group : {&distance, &weight})
      for (Plane& row : *group) row.assign(kRawWidth, 0.0f);
  }
};

// The rows a thread works on lie in rings of this many rows (row y in slot y % kRing): stage 2
// of row y reads the phasors of rows y - 1 .. y + 1 while row y + 1 is the newest, stage 3 the
// stage-2 rows y - 1 .. y + 1. A few rows stay in cache where whole-frame planes would not.
constexpr int kRing = 4;

// A ring of kRing rows.
struct RowRing {
  Plane rows = Plane(static_cast<size_t>(kRing) * kRawWidth);
  float* row(int y) { return rows.data() + static_cast<size_t>(y % kRing) * kRawWidth; }
  const float* row(int y) const {
    return rows.data() + static_cast<size_t>(y % kRing) * kRawWidth;
  }
};

// Row buffers of one thread.
struct Scratch {
  std::array<Plane, 9> values;      // unpacked correlations of the nine sub-images
  std::array<Plane, 3> amplitude;   // per frequency
  std::array<RowRing, 3> a, b, unit_a, unit_b;  // phasors per frequency (stage 1)
  RowRing depth_mm, edge_depth_mm, ir_sum;      // stage 2
  std::array<Plane, 3> filtered_a, filtered_b;
  Plane edge_ok;
  Plane ones;
  // Per frequency: pairs of row y-1 and of row y with the row below, and of row y within itself.
  std::array<PairRow, 3> down_above, down_here, right_here;
  int down_above_row = -1;  // the row whose pairs down_above holds

  Scratch() {
    for (auto* group : {&amplitude, &filtered_a, &filtered_b})
      for (Plane& row : *group) row.resize(kRawWidth);
    for (Plane& row : values) row.resize(kRawWidth);
    edge_ok.resize(kRawWidth);
    ones.assign(kRawWidth, 1.0f);
  }
};

}  // namespace

Status check_decoder_options(const DepthDecoderOptions& o) {
  if (!(std::isfinite(o.min_depth_m) && o.min_depth_m >= 0.0f))
    return invalid_argument("depth decoder: min_depth_m must be finite and >= 0, got " +
                            std::to_string(o.min_depth_m));
  if (!(std::isfinite(o.max_depth_m) && o.max_depth_m > o.min_depth_m))
    return invalid_argument("depth decoder: max_depth_m must be finite and greater than "
                            "min_depth_m, got " +
                            std::to_string(o.max_depth_m));
  if (o.threads != 1 && o.threads != 2)
    return invalid_argument("depth decoder: threads must be 1 or 2, got " +
                            std::to_string(o.threads));
  return Status::ok();
}

class DepthDecoder::Impl {
 public:
  Impl(const P0Tables& p0, const IrCalibration& calibration, const DepthDecoderOptions& options)
      : options_(options),
        constants_(kernels::make_kernel_constants(DecodeConstants{}, options.min_depth_m,
                                                  options.max_depth_m)),
        rays_(make_ray_tables(calibration)),
        phases_(make_phase_tables(p0, DecodeConstants{})),
        steps_{{phases_.cos_step[0], phases_.cos_step[1], phases_.cos_step[2]},
               {phases_.sin_step[0], phases_.sin_step[1], phases_.sin_step[2]}},
        scratch_(options.threads) {
    for (int code = 0; code < 2048; ++code) code_value_[code] = code_to_correlation()[code];
    if (options.threads == 2) helper_ = std::make_unique<HelperThread>();
  }

  Status decode(const RawDepthPacket& packet, DepthImage* depth, IrImage* ir) {
    DF_RETURN_IF_ERROR(accept(packet));
    depth->width = kRawWidth;
    depth->height = kRawHeight;
    depth->depth_m.resize(kRawPixels);
    decode_accepted(packet, depth->depth_m.data(), 0.001f, ir);
    return Status::ok();
  }

  Status decode_millimetres(const RawDepthPacket& packet, float* depth_mm, IrImage* ir) {
    if (depth_mm == nullptr) return invalid_argument("depth decoder: no output for the depth");
    DF_RETURN_IF_ERROR(accept(packet));
    decode_accepted(packet, depth_mm, 1.0f, ir);
    return Status::ok();
  }

  void restart_sequence() { have_sequence_ = false; }

 private:
  // The packet's checks; when it passes, its sequence number is the last one seen.
  Status accept(const RawDepthPacket& packet) {
    if (packet.bytes == nullptr)
      return invalid_argument("depth packet " + std::to_string(packet.sequence) + " has no data");
    if (packet.size != kRawPacketBytes)
      return invalid_argument("depth packet " + std::to_string(packet.sequence) + " has " +
                              std::to_string(packet.size) + " bytes, expected " +
                              std::to_string(kRawPacketBytes) + " (10 sub-images of 512x424 "
                              "11-bit codes)");
    if (have_sequence_ && static_cast<int32_t>(packet.sequence - last_sequence_) <= 0)
      return invalid_argument("depth packet sequence " + std::to_string(packet.sequence) +
                              " does not follow " + std::to_string(last_sequence_) +
                              " (repeated or out of order)");
    have_sequence_ = true;
    last_sequence_ = packet.sequence;
    return Status::ok();
  }

  // Depth goes out in units of which `per_mm` make a millimetre, straight from the kernels.
  void decode_accepted(const RawDepthPacket& packet, float* depth_out, float per_mm, IrImage* ir) {
    if (ir) {
      ir->width = kRawWidth;
      ir->height = kRawHeight;
      ir->amplitude.resize(kRawPixels);
    }
    packet_ = packet.bytes;
    depth_out_ = depth_out;
    per_mm_ = per_mm;
    ir_out_ = ir ? ir->amplitude.data() : nullptr;

    run([this](Scratch& s, int first, int last) { decode_rows(s, first, last); });
  }

  template <typename Rows>
  void run(Rows rows) {
    if (!helper_) {
      rows(scratch_[0], 0, kRawHeight);
      return;
    }
    // The first half runs on this thread, the second on the helper.
    const std::function<void(int, int)> job = [&](int first, int last) {
      rows(scratch_[first == 0 ? 0 : 1], first, last);
    };
    helper_->split(0, kRawHeight, job);
  }

  static size_t row_start(int y) { return static_cast<size_t>(y) * kRawWidth; }

  // The output rows [first, last), each stage of a row as soon as the rows it reads are done,
  // while they are in cache. Stage 3 of a row needs stage 2 of its neighbours, which needs the
  // phasors of theirs: a thread also does stage 1 of the two rows and stage 2 of the one row
  // beyond each end of its range (the other thread's; a few rows of 424 done twice).
  void decode_rows(Scratch& s, int first, int last) {
    s.down_above_row = -1;
    const int correlate_first = std::max(first - 2, 0);
    const int correlate_last = std::min(last + 2, kRawHeight);
    const int unwrap_last = std::min(last + 1, kRawHeight);
    int next_unwrap = std::max(first - 1, 0);
    int next_finish = first;
    for (int y = correlate_first; y < correlate_last; ++y) {
      correlate(s, y, /*ir=*/y >= first && y < last);
      // Stage 2 of row r reads rows r - 1 .. r + 1; stage 3 of row r their stage 2.
      const bool all_correlated = y == correlate_last - 1;
      while (next_unwrap < unwrap_last && (next_unwrap + 1 <= y || all_correlated))
        unwrap(s, next_unwrap++);
      while (next_finish < last &&
             (next_finish + 1 < next_unwrap || (all_correlated && next_unwrap == unwrap_last)))
        finish(s, next_finish++);
    }
  }

  // Stage 1: the packet's nine sub-images to phasors; the IR output when `ir`.
  void correlate(Scratch& s, int y, bool ir) {
    const size_t row = row_start(y);
    const size_t storage = static_cast<size_t>(packet_storage_row(y)) * kRawRowBytes;
    for (int i = 0; i < 9; ++i)
      kernels::unpack_row(packet_ + i * kRawSubImageBytes + storage, code_value_.data(),
                          s.values[i].data());
    for (int f = 0; f < 3; ++f) {
      const int k = 3 * f;
      kernels::correlate_row(
          s.values[k].data(), s.values[k + 1].data(), s.values[k + 2].data(),
          phases_.cos_p0[f].data() + row, phases_.sin_p0[f].data() + row,
          rays_.z_mm_per_phase.data() + row, steps_, constants_.firmware.ab_multiplier_per_frequency[f],
          constants_.firmware.ab_multiplier,
          kernels::PhasorRow{s.a[f].row(y), s.b[f].row(y), s.unit_a[f].row(y),
                             s.unit_b[f].row(y), s.amplitude[f].data()});
    }
    if (ir_out_ && ir)
      kernels::ir_row(s.amplitude[0].data(), s.amplitude[1].data(), s.amplitude[2].data(),
                      constants_.firmware.ab_output_multiplier, ir_out_ + row_start(kRawHeight - 1 - y));
  }

  static kernels::PhasorRows phasor_rows(const Scratch& s, int f, int y) {
    return {s.a[f].row(y), s.b[f].row(y)};
  }

  // The pairs of row r's pixels with those of row r + 1.
  void down_pairs(const Scratch& s, int f, int r, PairRow& out) const {
    const float* ua = s.unit_a[f].row(r);
    const float* ub = s.unit_b[f].row(r);
    const float* qa = s.unit_a[f].row(r + 1);
    const float* qb = s.unit_b[f].row(r + 1);
    kernels::pair_weights(ua + 1, ub + 1, qa, qb, kRawWidth - 1, constants_,
                          out.distance[0].data() + 1, out.weight[0].data() + 1);
    kernels::pair_weights(ua, ub, qa, qb, kRawWidth, constants_, out.distance[1].data(),
                          out.weight[1].data());
    kernels::pair_weights(ua, ub, qa + 1, qb + 1, kRawWidth - 1, constants_,
                          out.distance[2].data() + 1, out.weight[2].data() + 1);
  }

  // The pairs of row r's pixels with their right neighbours.
  void right_pairs(const Scratch& s, int f, int r, PairRow& out) const {
    const float* ua = s.unit_a[f].row(r);
    const float* ub = s.unit_b[f].row(r);
    kernels::pair_weights(ua, ub, ua + 1, ub + 1, kRawWidth - 1, constants_,
                          out.distance[0].data() + 1, out.weight[0].data() + 1);
  }

  // Pixel x's pairs with its eight neighbours, each read at index x.
  static kernels::NeighbourPairs neighbour_pairs(const PairRow& above, const PairRow& here,
                                                 const PairRow& right) {
    kernels::NeighbourPairs pairs{};
    const std::array<const PairRow*, 8> rows{&above, &above, &above, &right,
                                             &right, &here,  &here,  &here};
    const std::array<int, 8> slots{2, 1, 0, 0, 0, 0, 1, 2};
    const std::array<int, 8> shifts{0, 0, 1, 0, 1, 0, 0, 1};
    for (int n = 0; n < 8; ++n) {
      pairs.distance[n] = rows[n]->distance[slots[n]].data() + shifts[n];
      pairs.weight[n] = rows[n]->weight[slots[n]].data() + shifts[n];
    }
    return pairs;
  }

  // Stage 2: the bilateral filter (inner rows), phase unwrapping and depth.
  void unwrap(Scratch& s, int y) {
    const size_t row = row_start(y);
    kernels::UnwrapInput in{};
    in.z = rays_.z_mm_per_phase.data() + row;
    in.x = rays_.x_scaled.data() + row;
    const float* edge_ok = s.ones.data();
    if (options_.bilateral_filter && y > 0 && y < kRawHeight - 1) {
      std::fill(s.edge_ok.begin(), s.edge_ok.end(), 1.0f);
      // Rows are visited in order, so the pairs of row y - 1 are those row y made last time.
      if (s.down_above_row != y - 1)
        for (int f = 0; f < 3; ++f) down_pairs(s, f, y - 1, s.down_above[f]);
      for (int f = 0; f < 3; ++f) {
        down_pairs(s, f, y, s.down_here[f]);
        right_pairs(s, f, y, s.right_here[f]);
        float* fa = s.filtered_a[f].data();
        float* fb = s.filtered_b[f].data();
        for (int x : {0, kRawWidth - 1}) {
          fa[x] = s.a[f].row(y)[x];
          fb[x] = s.b[f].row(y)[x];
        }
        kernels::bilateral_row(
            phasor_rows(s, f, y - 1), phasor_rows(s, f, y), phasor_rows(s, f, y + 1),
            neighbour_pairs(s.down_above[f], s.down_here[f], s.right_here[f]), constants_, fa, fb,
            s.edge_ok.data());
        in.a[f] = fa;
        in.b[f] = fb;
      }
      std::swap(s.down_above, s.down_here);
      s.down_above_row = y;
      edge_ok = s.edge_ok.data();
    } else {
      for (int f = 0; f < 3; ++f) {
        in.a[f] = s.a[f].row(y);
        in.b[f] = s.b[f].row(y);
      }
    }
    kernels::unwrap_row(in, edge_ok, constants_, s.depth_mm.row(y), s.edge_depth_mm.row(y),
                        s.ir_sum.row(y));
  }

  static kernels::EdgeRows edge_rows(const Scratch& s, int y) {
    return {s.depth_mm.row(y), s.edge_depth_mm.row(y), s.ir_sum.row(y)};
  }

  // Stage 3: the edge-aware filter (inner rows) and the output in its unit, flipped upright.
  void finish(const Scratch& s, int y) {
    float* out = depth_out_ + row_start(kRawHeight - 1 - y);
    const float* raw = s.depth_mm.row(y);
    if (!options_.edge_aware_filter)
      kernels::depth_row(raw, /*range_check=*/false, constants_, per_mm_, out);
    else if (y == 0 || y == kRawHeight - 1)
      kernels::depth_row(raw, /*range_check=*/true, constants_, per_mm_, out);
    else
      kernels::edge_filter_row(edge_rows(s, y - 1), edge_rows(s, y), edge_rows(s, y + 1),
                               constants_, per_mm_, out);
  }

  const DepthDecoderOptions options_;
  const kernels::KernelConstants constants_;
  const RayTables rays_;
  const PhaseTables phases_;
  const kernels::PhaseSteps steps_;
  std::array<float, 2048> code_value_{};
  std::vector<Scratch> scratch_;
  std::unique_ptr<HelperThread> helper_;
  const uint8_t* packet_ = nullptr;
  float* depth_out_ = nullptr;
  float per_mm_ = 0.001f;
  float* ir_out_ = nullptr;
  bool have_sequence_ = false;
  uint32_t last_sequence_ = 0;
};

Result<std::unique_ptr<DepthDecoder>> DepthDecoder::create(const P0Tables& p0,
                                                           const IrCalibration& calibration,
                                                           const DepthDecoderOptions& options) {
  DF_RETURN_IF_ERROR(check_decoder_options(options));
  DF_RETURN_IF_ERROR(check_p0_tables(p0).with_context("depth decoder"));
  DF_RETURN_IF_ERROR(check_ir_calibration(calibration).with_context("depth decoder"));
  return std::unique_ptr<DepthDecoder>(
      new DepthDecoder(std::make_unique<Impl>(p0, calibration, options)));
}

DepthDecoder::DepthDecoder(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
DepthDecoder::~DepthDecoder() = default;

Status DepthDecoder::decode(const RawDepthPacket& packet, DepthImage* depth, IrImage* ir) {
  return impl_->decode(packet, depth, ir);
}

Status DepthDecoder::decode_millimetres(const RawDepthPacket& packet, float* depth_mm,
                                        IrImage* ir) {
  return impl_->decode_millimetres(packet, depth_mm, ir);
}

void DepthDecoder::restart_sequence() { impl_->restart_sequence(); }


}  // namespace depthfuse::kinect2
