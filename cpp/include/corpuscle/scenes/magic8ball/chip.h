// The Magic 8-Ball on chip: one tile (a CUDA block) per scene, the scene's particles, ghosts,
// cell table, record and reductions in the block's shared memory, K steps per launch.
//
// The physics is the general path's (stages.h: density_of, tait_pressure, ForceVisitor,
// particle_forces, FinalizeStage, integrate_particle; the walks of spatial/lane_walks.h and
// the lists of spatial/neighbor_list.h); only where the data live and how the loops run
// differ. A step on chip is the lists index's step:
//
//   - rebuilding(m, scene) (a new state, or the scene moved by more than its skin since the
//     last rebuild, moved_too_far): the scene's fluid and ghost entries are keyed by cell and
//     sorted in shared memory (a bitonic sort of (layer, cell key, entry) words: the entry
//     below the key keeps it stable, so the order is the general path's stable radix sort's),
//     gathered into that order, the ghosts made, x_build set, the cell table marked, and
//     every particle's list of neighbours within h (1 + skin) made by the cell walk;
//   - every step: the density walks the list and keeps the entries within h (the near list),
//     the forces walk the near list.
// The lists are the only arrays outside shared memory (the pipeline's list buffers, the
// scene's rows, holding slots of the scene's block): a particle's candidates are tested once
// per rebuild, not every step (a cell walk tests about ten candidates per neighbour within h).
//
// The reductions of a step are summed per lane group in a fixed order, then the groups in
// order by one thread: deterministic, though not the general path's order (float sums agree
// to rounding). The control is read once per step (it does not change within a launch: the
// host writes it between launches), the end time and the halting flags exactly as in the
// general path's FinalizeStage. At a launch's start the order, x_build, ghosts and lists are
// the state's (the general path's lists hold other slot numbers: a state it stepped last is
// relisted, the pipeline raises every scene's rebuild). At its end the state is written to
// the other buffers (the pipeline's parity flips as after a general step).
//
// On the CPU the tile runs its lanes one after another (CpuTile): the same code, which the
// tests use to check the chip path's logic against the general path without a device.
#pragma once
#include "corpuscle/core/lanes.h"
#include "corpuscle/scenes/magic8ball/stages.h"
#include "corpuscle/spatial/lane_walks.h"

namespace cps::m8 {

constexpr int kChipThreads = 512;  // threads of a scene's block
constexpr int kChipLanes = 8;      // lanes per particle in the pair passes
constexpr int kChipGroups = kChipThreads / kChipLanes;
constexpr int kChipStage = 64;     // list entries a group stages in shared memory at once

// where a scene's arrays lie in its block's shared memory (byte offsets, 16-aligned)
struct ChipLayout {
  int n = 0;         // fluid slots of a scene (ghost slots: as many)
  int sort_n = 0;    // the sort's entries: a power of two >= 2 n
  int idx_bits = 0;  // bits of an entry (< 2 n) in a sort word
  int key_bits = 0;  // bits of a cell key (the grid's, tag included)
  int cells = 0;     // cell table entries (both tags)
  size_t rec = 0, parts = 0, stage = 0, pos = 0, vel = 0, rho = 0, terms = 0, scratch = 0, xb = 0, id = 0, gslot = 0,
         keys = 0, cstart = 0, cend = 0, total = 0;
  // the sort words fit 32 bits: layer, cell key, entry
  CPS_HD bool words_fit() const { return 1 + key_bits + idx_bits <= 32; }
};

CPS_HD CPS_INLINE size_t chip_align(size_t b) { return (b + 15) / 16 * 16; }

CPS_HD CPS_INLINE ChipLayout chip_layout(const Model& m) {
  ChipLayout L;
  L.n = m.n_fluid;
  const int slots = 2 * L.n;
  L.sort_n = 1;
  while (L.sort_n < slots) L.sort_n *= 2;
  L.idx_bits = 1;
  while ((1 << L.idx_bits) < slots) ++L.idx_bits;
  L.key_bits = key_bits(m);
  L.cells = int(cells_per_scene(m));
  size_t at = 0;
  auto take = [&](size_t& off, size_t bytes) {
    off = at;
    at = chip_align(at + bytes);
  };
  take(L.rec, sizeof(Scene));
  take(L.parts, sizeof(StepSums) * kChipGroups);
  take(L.stage, sizeof(int) * kChipGroups * kChipStage);
  take(L.pos, sizeof(Vec3) * slots);
  take(L.vel, sizeof(Vec3) * slots);
  take(L.rho, sizeof(float) * slots);
  take(L.terms, sizeof(ForceTerms) * slots);
  take(L.scratch, sizeof(Vec3) * slots);  // the fluid's acceleration, then its XSPH correction; a rebuild's gathers
  take(L.xb, sizeof(Vec3) * L.n);
  take(L.id, sizeof(int) * L.n);
  take(L.gslot, sizeof(int) * L.n);
  take(L.keys, sizeof(uint32_t) * L.sort_n);
  take(L.cstart, sizeof(uint32_t) * L.cells);
  take(L.cend, sizeof(uint32_t) * L.cells);
  L.total = at;
  return L;
}

// the pointers into a block's shared memory
struct ChipSmem {
  Scene* rec;
  StepSums* parts;
  int* stage;  // kChipStage list entries per lane group
  Vec3 *pos, *vel, *acc, *xsph, *tmp, *xb;
  float* rho;
  ForceTerms* terms;
  int *id, *gslot, *itmp;
  uint32_t *keys, *cstart, *cend;
  CPS_HD static ChipSmem at(unsigned char* base, const ChipLayout& L) {
    ChipSmem s;
    s.rec = reinterpret_cast<Scene*>(base + L.rec);
    s.parts = reinterpret_cast<StepSums*>(base + L.parts);
    s.stage = reinterpret_cast<int*>(base + L.stage);
    s.pos = reinterpret_cast<Vec3*>(base + L.pos);
    s.vel = reinterpret_cast<Vec3*>(base + L.vel);
    s.rho = reinterpret_cast<float*>(base + L.rho);
    s.terms = reinterpret_cast<ForceTerms*>(base + L.terms);
    s.tmp = reinterpret_cast<Vec3*>(base + L.scratch);
    s.acc = s.tmp;
    s.xsph = s.tmp + L.n;
    s.itmp = reinterpret_cast<int*>(base + L.scratch);
    s.xb = reinterpret_cast<Vec3*>(base + L.xb);
    s.id = reinterpret_cast<int*>(base + L.id);
    s.gslot = reinterpret_cast<int*>(base + L.gslot);
    s.keys = reinterpret_cast<uint32_t*>(base + L.keys);
    s.cstart = reinterpret_cast<uint32_t*>(base + L.cstart);
    s.cend = reinterpret_cast<uint32_t*>(base + L.cend);
    return s;
  }
};

// a lane group's lane and width (the CPU's one lane; a device's SubWarpLanes<W>), and a barrier
// of the group (its lanes' shared-memory writes seen by all of them)
CPS_HD CPS_INLINE int group_lane(const SingleLane&) { return 0; }
CPS_HD CPS_INLINE void group_sync(const SingleLane&) {}
#ifdef __CUDACC__
template <int W>
__device__ int group_lane(const SubWarpLanes<W>& L) { return L.lane(); }
template <int W>
__device__ void group_sync(const SubWarpLanes<W>& L) { __syncwarp(L.mask()); }
#endif

// walk the c entries of a list row (global memory) through the group's staging buffer in
// shared memory, kChipStage at a time: every lane loads its entries of a chunk at once (one
// memory latency a chunk, not one an entry), then walk(chunk, count, offset) visits them. A
// chunk is a whole number of lane rounds, so each lane visits the entries it would visit
// walking the row itself, in the same order: the same sums
template <class Ln, class Walk>
CPS_HD void staged_rows(const Ln& L, int* buf, const int* row, int c, Walk&& walk) {
  constexpr int kMost = kChipStage;
  group_sync(L);  // the row's entries, just written by the group's lanes (a rebuild's listing, the density's near list)
  for (int c0 = 0; c0 < c; c0 += kMost) {
    const int cn = c - c0 < kMost ? c - c0 : kMost;
#ifdef __CUDA_ARCH__
    constexpr int kPer = kChipStage / kChipLanes;
    int v[kPer];
#pragma unroll
    for (int k = 0; k < kPer; ++k) {
      const int e = group_lane(L) + k * kChipLanes;
      v[k] = e < cn ? row[c0 + e] : 0;
    }
#pragma unroll
    for (int k = 0; k < kPer; ++k) {
      const int e = group_lane(L) + k * kChipLanes;
      if (e < cn) buf[e] = v[k];
    }
#else
    for (int e = 0; e < cn; ++e) buf[e] = row[c0 + e];
#endif
    group_sync(L);
    walk(static_cast<const int*>(buf), cn, c0);
    group_sync(L);  // (the next chunk overwrites the buffer)
  }
}

// g(i, L, acc) for i in [0, n) by groups of kChipLanes lanes (the CPU: one lane a group), the
// group's items in a fixed order; done(group, acc) by each group's leader once its items are
// done (every group, with or without items)
template <class Tile, class Acc, class G, class Done>
CPS_HD void chip_groups(Tile& t, int n, const Acc& init, G&& g, Done&& done) {
  t.lanes([&](int l) {
#ifdef __CUDA_ARCH__
    const SubWarpLanes<kChipLanes> L;
#else
    if (l % kChipLanes) return;
    const SingleLane L;
#endif
    const int group = l / kChipLanes;
    Acc acc = init;
    for (int i = group; i < n; i += kChipGroups) g(i, L, acc, group);
    if (L.leader()) done(group, acc);
  });
}

// f(i) for i in [0, n), one lane each
template <class Tile, class F>
CPS_HD void chip_items(Tile& t, int n, F&& f) {
  t.lanes([&](int l) {
    for (int i = l; i < n; i += Tile::kSize) f(i);
  });
}

// a sort word: layer (0 fluid, 1 ghost), cell key, entry (the stable order's tie-break)
CPS_HD CPS_INLINE uint32_t chip_word(const ChipLayout& L, int layer, uint32_t key, int entry) {
  return (uint32_t(layer) << (L.key_bits + L.idx_bits)) | (key << L.idx_bits) | uint32_t(entry);
}

// K steps of every scene, a tile per scene (see the top of this file)
struct ChipStage {
  const Model* model;
  Scene* g;
  const Control* ctl;
  Arrays a;   // the current buffers (read), their *_alt (written): the state after the launch
  int steps;  // steps of this launch

  template <class Tile>
  CPS_HD void operator()(int s, Tile& t) const {
    const Model& m = *model;
    const ChipLayout L = chip_layout(m);
    ChipSmem S = ChipSmem::at(t.template shared<unsigned char>(L.total), L);
    const int n = L.n, N = total_fluid(m), base = s * n, gbase = N + s * n;
    // load the scene
    t.lanes([&](int l) {
      if (l == 0) *S.rec = g[s];
    });
    t.sync();
    const int n_ghost = S.rec->n_ghost;
    chip_items(t, n, [&](int q) {
      S.pos[q] = a.position[base + q];
      S.vel[q] = a.velocity[base + q];
      S.id[q] = a.id[base + q];
      S.xb[q] = a.x_build[base + q];
      const int gs = a.ghost_slot[base + q];
      S.gslot[q] = gs >= 0 ? gs - gbase + n : -1;
      if (q < n_ghost) {
        S.pos[n + q] = a.position[gbase + q];
        S.vel[n + q] = a.velocity[gbase + q];
      }
    });
    t.sync();
    const int n_active = S.rec->phys.n_active;
    const float h2 = m.kern.support2();
    CellGridView<D> grid;
    grid.spec = m.grid;
    grid.pos = S.pos;
    grid.cell_start = S.cstart;
    grid.cell_end = S.cend;
    grid.n = 2 * n;
    grid.r2 = m.list_radius * m.list_radius;  // the lists' reach
    grid.tag_end = 2;
    // the scene's rows of the lists (entries: slots of this block)
    const RowLists lists{a.nbr + size_t(base) * size_t(m.max_neighbors), a.nbr_count + base, m.max_neighbors};
    const RowLists near{a.near + size_t(base) * size_t(m.max_near), a.near_count + base, m.max_near};
    for (int k = 0; k < steps; ++k) {
      if (halted(S.rec)) {  // (uniform: every lane reads the record after a barrier)
        t.lanes([&](int l) {
          if (l == 0) FinalizeStage{model, S.rec, nullptr}(0);  // as the general path's no-op steps leave it
        });
        t.sync();
        break;
      }
      const bool relist = rebuilding(m, S.rec);
      if (relist) rebuild(t, S, L, n_active);
      // density and pressure (and the container frame of this step); on rebuilds the lists
      // first (the cells walked), then every step the list walked, its entries within h kept
      const ScenePhysics& P = S.rec->phys;
      t.lanes([&](int l) {
        if (l == 0) prepare_frame(m, ctl[s], *S.rec);
      });
      chip_groups(t, n_active, 0, [&](int i, const auto& Ln, int&, int group) {
        DensityVisitor<D> v{m.kern};
        const Vec3 x = S.pos[i];
        int count = 0;
        if (relist) {
          NoVisit none;
          count = for_each_in_cells(Ln, grid, x, none, lists.row(i), m.max_neighbors);
        } else {
          count = lists.count[i];
        }
        int kept = 0;
        int* out = near.row(i);
        staged_rows(Ln, S.stage + group * kChipStage, lists.row(i), lists.stored(count),
                    [&](const int* chunk, int cn, int) {
                      kept += for_each_listed_compacting(Ln, chunk, cn, S.pos, x, v, h2, out + kept,
                                                         near.capacity - kept);
                    });
        const float sum = Ln.sum(v.sum);
        if (!Ln.leader()) return;
        near.count[i] = kept;
        if (count > m.max_neighbors || kept > m.max_near) raise_first(&S.rec->clock.bad, kBadNeighbors);
        if (relist) lists.count[i] = count;
        const float rho = density_of(m, P, S.rec->die, x, sum);
        const ForceTerms ft = ForceTerms::of(rho, tait_pressure(P.sph, rho));
        S.rho[i] = rho;
        S.terms[i] = ft;
        const int ghost = S.gslot[i];
        if (ghost >= 0) {
          S.rho[ghost] = rho;
          S.terms[ghost] = ft;
        }
      }, [](int, int) {});
      t.sync();
      // forces, the die's reactions and the step's reductions
      chip_groups(t, n_active, StepSums::identity(), [&](int i, const auto& Ln, StepSums& acc, int group) {
        const Vec3 x = S.pos[i];
        ForceVisitor<D> fv(m.kern, P.sph, S.vel, S.rho, S.terms, i, n);
        staged_rows(Ln, S.stage + group * kChipStage, near.row(i), near.listed(i),
                    [&](const int* chunk, int cn, int) { for_each_listed(Ln, chunk, cn, S.pos, x, fv); });
        fv.reduce(Ln);
        if (!Ln.leader()) return;
        acc = StepSums::combine(acc, particle_forces(m, *S.rec, P, x, S.vel[i], S.rho[i], fv.s, S.acc[i], S.xsph[i]));
      }, [&](int group, const StepSums& acc) { S.parts[group] = acc; });
      t.sync();
      // dt, die, shell, clock
      t.lanes([&](int l) {
        if (l != 0) return;
        StepSums total = StepSums::identity();
        for (int q = 0; q < kChipGroups; ++q) total = StepSums::combine(total, S.parts[q]);
        S.rec->pending = total;
        FinalizeStage{model, S.rec, nullptr}(0);
      });
      t.sync();
      // the fluid (and its ghosts) moved by the step's dt
      if (S.rec->step_dt > 0.0f) {
        chip_items(t, n_active, [&](int i) {
          const int ghost = S.gslot[i];
          integrate_particle(m, S.rec, S.acc[i], S.xsph[i], S.xb[i], S.pos[i], S.vel[i],
                             ghost >= 0 ? S.pos + ghost : nullptr, ghost >= 0 ? S.vel + ghost : nullptr);
        });
      }
      t.sync();
    }
    // the state, into the other buffers (moving fields) and the single ones
    const int ng = S.rec->n_ghost;
    chip_items(t, n, [&](int q) {
      a.position_alt[base + q] = S.pos[q];
      a.velocity_alt[base + q] = S.vel[q];
      a.id_alt[base + q] = S.id[q];
      a.x_build[base + q] = S.xb[q];
      a.ghost_slot[base + q] = S.gslot[q] >= 0 ? S.gslot[q] - n + gbase : -1;
      if (q < n_active) {
        const float rho = S.rho[q];
        a.density[base + q] = rho;
        a.pressure[base + q] = tait_pressure(S.rec->phys.sph, rho);
        a.acceleration[base + q] = S.acc[q];
      }
      if (q < ng) {
        const float rho = S.rho[n + q];
        a.position_alt[gbase + q] = S.pos[n + q];
        a.velocity_alt[gbase + q] = S.vel[n + q];
        a.id_alt[gbase + q] = -1;
        a.density[gbase + q] = rho;
        a.pressure[gbase + q] = tait_pressure(S.rec->phys.sph, rho);
      }
    });
    t.lanes([&](int l) {
      if (l == 0) g[s] = *S.rec;
    });
  }

  // the cell table from the sort words in S.keys[0, 2n) (sorted: a cell's slots consecutive)
  template <class Tile>
  CPS_HD void mark(Tile& t, const ChipSmem& S, const ChipLayout& L) const {
    const Model& m = *model;
    const uint32_t unused = unused_key(m), kmask = (L.key_bits >= 32 ? ~0u : ((1u << L.key_bits) - 1u));
    const int slots = 2 * L.n;
    chip_items(t, slots, [&](int q) {
      const uint32_t w = S.keys[q] >> L.idx_bits, k = w & kmask;
      if (k == unused) return;
      const uint32_t slot = uint32_t(m.grid.slot_of_key(k));
      if (q == 0 || (S.keys[q - 1] >> L.idx_bits) != w) S.cstart[slot] = uint32_t(q);
      if (q + 1 == slots || (S.keys[q + 1] >> L.idx_bits) != w) S.cend[slot] = uint32_t(q + 1);
    });
    t.sync();
  }

  // sort the scene by cell (fluid, then its ghosts made anew), gather it into that order and
  // mark the cells: ReorderStage's work, in shared memory
  template <class Tile>
  CPS_HD void rebuild(Tile& t, const ChipSmem& S, const ChipLayout& L, int n_active) const {
    const Model& m = *model;
    const int n = L.n, P = L.sort_n;
    const uint32_t unused = unused_key(m), emask = (1u << L.idx_bits) - 1u;
    // keys (the entry below: a stable order) and a cleared cell table
    chip_items(t, P > L.cells ? P : L.cells, [&](int e) {
      if (e < L.cells) S.cstart[e] = S.cend[e] = 0u;
      if (e >= P) return;
      if (e >= 2 * n) {
        S.keys[e] = ~0u;  // padding: past every entry
      } else if (e < n) {
        S.keys[e] = chip_word(L, 0, e < n_active ? cell_key(m, S.pos[e], 0) : unused, e);
      } else {
        const int f = e - n;
        const Vec3 x = S.pos[f];
        const bool ghost = f < n_active && needs_ghost(m.wall, x, m.list_radius);
        S.keys[e] = chip_word(L, 1, ghost ? cell_key(m, mirror_position(m.wall, x), 1) : unused, e);
      }
    });
    t.sync();
    // bitonic sort of the words (distinct: the entry is part of each)
    for (int size = 2; size <= P; size <<= 1) {
      for (int stride = size >> 1; stride > 0; stride >>= 1) {
        chip_items(t, P, [&](int i) {
          const int j = i ^ stride;
          if (j <= i) return;
          const uint32_t x = S.keys[i], y = S.keys[j];
          if ((x > y) == ((i & size) == 0)) {
            S.keys[i] = y;
            S.keys[j] = x;
          }
        });
        t.sync();
      }
    }
    // sorted slot q takes entry e = word & emask: fluid q < n from fluid slot e; ghost slot
    // n + g from the fluid slot e - n it mirrors (valid while its key is not unused)
    auto valid_ghost = [&](int q) { return ((S.keys[q] >> L.idx_bits) & ((1u << L.key_bits) - 1u)) != unused; };
    int* id_new = S.itmp;          // [0, n)
    int* ghost_of = S.itmp + n;    // old fluid slot -> its new ghost slot
    chip_items(t, n, [&](int q) {
      id_new[q] = S.id[S.keys[q] & emask];
      ghost_of[q] = -1;
    });
    t.lanes([&](int l) {
      if (l == 0) S.rec->n_ghost = 0;
    });
    t.sync();
    chip_items(t, n, [&](int gq) {
      const int q = n + gq;
      if (!valid_ghost(q)) return;
      ghost_of[int(S.keys[q] & emask) - n] = q;
      if (q + 1 == 2 * n || !valid_ghost(q + 1)) S.rec->n_ghost = gq + 1;
    });
    t.sync();
    chip_items(t, n, [&](int q) {
      S.id[q] = id_new[q];
      S.gslot[q] = ghost_of[S.keys[q] & emask];
    });
    t.sync();
    // velocities (a ghost's from its particle's old position and velocity), then positions
    chip_items(t, 2 * n, [&](int q) {
      const int e = int(S.keys[q] & emask);
      if (q < n) S.tmp[q] = S.vel[e];
      else if (valid_ghost(q)) S.tmp[q] = mirror_velocity(S.pos[e - n], S.vel[e - n]);
    });
    t.sync();
    chip_items(t, 2 * n, [&](int q) {
      if (q < n || valid_ghost(q)) S.vel[q] = S.tmp[q];
    });
    t.sync();
    chip_items(t, 2 * n, [&](int q) {
      const int e = int(S.keys[q] & emask);
      if (q < n) S.tmp[q] = S.pos[e];
      else if (valid_ghost(q)) S.tmp[q] = mirror_position(m.wall, S.pos[e - n]);
    });
    t.sync();
    chip_items(t, 2 * n, [&](int q) {
      if (q < n || valid_ghost(q)) S.pos[q] = S.tmp[q];
      if (q < n) S.xb[q] = S.tmp[q];
    });
    t.sync();
    mark(t, S, L);
  }
};

// the shared memory a scene's block needs on chip
inline size_t chip_bytes(const Model& m) { return chip_layout(m).total; }

// whether the scenes of m fit the chip path with `shared_limit` bytes of shared memory a block
inline bool chip_fits(const Model& m, size_t shared_limit) {
  const ChipLayout L = chip_layout(m);
  return L.words_fit() && L.total <= shared_limit;
}

}  // namespace cps::m8
