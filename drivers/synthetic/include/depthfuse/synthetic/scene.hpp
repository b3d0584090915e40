// Analytic scenes for the synthetic frame source: rectangles of planes, axis-aligned boxes and
// rooms (the inside of a box). They are the exact ground truth of everything the synthetic source
// renders: raycasting gives noise-free depth, distance_m() measures how far a reconstructed point
// lies from the true surface, and to_toml()/parse_toml() let a written folder carry its own ground
// truth.
//
// World frame of the built-in scenes: z up, floor at z = 0, metres.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "depthfuse/status.hpp"

namespace depthfuse::synthetic {

enum class SceneKind { kCorner, kRoom, kRooms, kFurnished, kPlain };
const char* to_string(SceneKind kind);  // "corner", "room", "rooms", "furnished", "plain"
Result<SceneKind> parse_scene_kind(const std::string& text);

enum class PrimitiveKind {
  kPlane,  // a plane restricted to a rectangle of its own (u, v) axes; bounds may be infinite
  kBox,    // a solid axis-aligned box: its outside is the surface
  kRoom,   // the inside of an axis-aligned box: floor, ceiling and four walls seen from within
};
const char* to_string(PrimitiveKind kind);  // "plane", "box", "room"

// One surface of a scene. Flat on purpose (one struct, a kind tag) so that it maps 1:1 to TOML.
struct Primitive {
  PrimitiveKind kind = PrimitiveKind::kBox;
  std::string name;  // optional label ("floor", "box3"), kept in TOML
  std::array<uint8_t, 3> color_rgb = {180, 180, 180};  // albedo for the rendered colour image
  // The colour image's texture: checker squares of this side (alternately full and 70 % albedo);
  // 0 = one plain colour (a painted wall, upholstery: no texture for the colour term to use).
  double checker_m = 0.25;

  // kPlane: points origin_m + a u_axis + b v_axis with a in [u_min_m, u_max_m], b in
  // [v_min_m, v_max_m], where v_axis = normal x u_axis. `normal` points to the free side (it
  // decides which side is "in front" for the multipath model; rays hit both sides). Infinite bounds
  // make a half-plane, a strip or a whole plane.
  Eigen::Vector3d origin_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d u_axis = Eigen::Vector3d::UnitX();
  double u_min_m = 0.0, u_max_m = 1.0;
  double v_min_m = 0.0, v_max_m = 1.0;

  // kBox, kRoom: the box [min_m, max_m].
  Eigen::Vector3d min_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d max_m = Eigen::Vector3d::Ones();

  Eigen::Vector3d v_axis() const { return normal.cross(u_axis); }

  static Primitive plane(const Eigen::Vector3d& origin_m, const Eigen::Vector3d& normal,
                         const Eigen::Vector3d& u_axis, double u_min_m, double u_max_m,
                         double v_min_m, double v_max_m, std::string name = {});
  static Primitive box(const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m,
                       std::string name = {});
  static Primitive room(const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m,
                        std::string name = {});
};

// What a ray hit.
struct RayHit {
  double t = 0.0;  // hit = origin + t * dir (metres if |dir| = 1)
  Eigen::Vector3d normal_w = Eigen::Vector3d::Zero();  // unit, on the side of the ray origin
  int primitive = -1;                                  // index into Scene::primitives()
  int face = 0;  // box/room: 2*axis + (0 = min side, 1 = max side)
  Eigen::Vector2d uv_m = Eigen::Vector2d::Zero();  // coordinates within the surface (texturing)
};

class Scene {
 public:
  Scene() = default;  // empty: every ray misses

  // Validates the primitives (unit normals, perpendicular axes, non-empty extents) and builds the
  // acceleration grid. Errors name the primitive.
  static Result<Scene> create(std::vector<Primitive> primitives, std::string name = {});

  // The built-in scenes (see scene_make.cpp); `seed` varies the box layout, never the trajectory's
  // free space.
  //  corner: floor and two walls, 3 x 3 m each, meeting at the origin; free space x, y, z > 0.
  //  room:   a 5 x 4 x 2.6 m room [0,5]x[0,4]x[0,2.6] with five boxes, one stacked on another.
  //  rooms:  a 4 x 4 grid of 5 x 5 m rooms ([0,20]x[0,20], 2.6 m high) with 0.1 m thick walls,
  //          1.2 m doorways between all neighbours and two or three boxes per room.
  //  furnished: a 5 x 4 x 2.6 m living room [0,5]x[0,4]x[0,2.6]: a 2.3 m sofa along the wall
  //          y = 4, a bookshelf with books, a door, a desk with a monitor, a cabinet with a lamp,
  //          a side table, a floor lamp and three pictures a few cm proud of the walls.
  //  plain:  the same room with bare walls and one low box.
  static Scene make(SceneKind kind, uint64_t seed);

  // Nearest hit with t in (0, t_max]. `dir_w` need not be unit: t is in multiples of it (the
  // renderer passes (x/z, y/z, 1) rays so that t is the depth).
  bool raycast(const Eigen::Vector3d& origin_w, const Eigen::Vector3d& dir_w, double t_max,
               RayHit* hit) const;
  // The same with unlimited range; t_m and normal_w (facing the origin) may be null.
  bool raycast(const Eigen::Vector3d& origin_w, const Eigen::Vector3d& dir_w, double* t_m,
               Eigen::Vector3d* normal_w) const;

  // Distance from p_w to the nearest surface point of the scene (infinity for an empty scene).
  double distance_m(const Eigen::Vector3d& p_w) const;

  // Multipath support: distance from p_w, a point on primitive `primitive` whose surface normal
  // facing the viewer is normal_w, to the nearest surface that forms a concave edge with it
  // (another surface in front of it whose free side contains p_w, or an adjacent wall of the same
  // room). Returns max_distance_m when there is none closer.
  double concave_edge_distance_m(const Eigen::Vector3d& p_w, const Eigen::Vector3d& normal_w,
                                 int primitive, int face, double max_distance_m) const;
  // The same over a candidate list only (the renderer's per-tile list of primitives near the view).
  double concave_edge_distance_m(const Eigen::Vector3d& p_w, const Eigen::Vector3d& normal_w,
                                 int primitive, int face, double max_distance_m,
                                 const int* candidates, size_t count) const;

  // The per-primitive terms of rays that all start at one origin (a camera centre), computed once
  // per view: six numbers per primitive.
  struct ViewCache {
    Eigen::Vector3d origin_w = Eigen::Vector3d::Zero();
    std::vector<double> terms;
  };
  void prepare_view(const Eigen::Vector3d& origin_w, ViewCache* view) const;

  // Raycast from view.origin_w against a candidate list sorted by t_lower[k], a lower bound of the
  // ray parameter of any hit on candidates[k]: stops at the first candidate that cannot beat the
  // best hit. The renderer uses it with per-tile lists culled against the view frustum.
  bool raycast_candidates(const ViewCache& view, const Eigen::Vector3d& dir_w,
                          const int* candidates, const double* t_lower, size_t count, double t_max,
                          RayHit* hit) const;

  const std::vector<Primitive>& primitives() const { return primitives_; }
  // Axis-aligned bounds of each primitive (infinite for unbounded planes).
  const std::vector<Eigen::AlignedBox3d>& primitive_bounds() const { return primitive_bounds_; }
  const std::string& name() const { return name_; }
  // Union of the bounded primitives' boxes (empty box when there are none).
  const Eigen::AlignedBox3d& bounds() const { return bounds_; }

  // TOML with a [scene] table and one [[primitive]] table per surface; round-trips exactly
  // (shortest decimal representation of every double).
  std::string to_toml() const;
  // Reads what to_toml() writes. Unknown keys are errors; other top-level tables (e.g. the
  // [generator] that write_tum_folder adds) are ignored. `origin` names the text in messages.
  static Result<Scene> parse_toml(const std::string& text,
                                  const std::string& origin = "scene.toml");
  static Result<Scene> load_toml(const std::string& path);

 private:
  // Per-primitive data in the form the hot loops want.
  struct Compact {
    PrimitiveKind kind;
    Eigen::Vector3d a;  // plane: origin;  box/room: min
    Eigen::Vector3d b;  // plane: normal;  box/room: max
    Eigen::Vector3d u;  // plane: u axis
    Eigen::Vector3d v;  // plane: v axis
    double u_min, u_max, v_min, v_max;
  };
  struct Ray;

  static void origin_terms(const Compact& c, const Eigen::Vector3d& origin_w, double* k);
  bool hit_nearer(int index, const double* k, Ray* ray, double* best, int* face) const;
  void fill_hit(int index, int face, double t, const Eigen::Vector3d& origin_w, const double* k,
                const Eigen::Vector3d& dir_w, RayHit* hit) const;
  double own_concave_distance(const Eigen::Vector3d& p_w, int primitive, int face,
                              double max_distance_m) const;
  void concave_visit(int i, const Eigen::Vector3d& p_w, const Eigen::Vector3d& normal_w,
                     int primitive, double* best) const;
  static double surface_distance(const Compact& c, const Eigen::Vector3d& p, double bound,
                                 Eigen::Vector3d* q, bool* outside);
  void traverse_grid(const Eigen::Vector3d& origin_w, Ray* ray, double* best_t, int* best_index,
                     int* best_face) const;
  void build_grid();
  template <typename Fn>
  void for_cells_in_xy_box(double x0, double y0, double x1, double y1, Fn&& fn) const;

  std::string name_;
  std::vector<Primitive> primitives_;
  std::vector<Compact> compact_;
  std::vector<Eigen::AlignedBox3d> primitive_bounds_;
  Eigen::AlignedBox3d bounds_;

  // A uniform 2-D grid over x-y (the scenes are flat: many rooms side by side, 2.6 m high). Each
  // cell lists the primitives whose bounding box overlaps it (CSR layout); primitives that are
  // unbounded or cover much of the grid are tested for every ray instead ("global").
  std::vector<int> global_;
  std::vector<int> cell_begin_;  // nx*ny + 1 offsets into cell_items_
  std::vector<int> cell_items_;
  double grid_x0_ = 0.0, grid_y0_ = 0.0, cell_m_ = 1.0;
  int nx_ = 0, ny_ = 0;
};

}  // namespace depthfuse::synthetic
