"""One SPH box scene split over MPI ranks (docs/distributed.md, "One scene over many ranks").
(It is longer than 600 lines: the decomposition, the halo refresh, the migration, the balancing
and the gather of the one output all act on one rank's state, and a step reads in one place.)

Every rank runs the same Python: the scene is built the same way on each, then each rank keeps
the particles of its slab (along the domain's longest axis without a periodic wrap, cut on
multiples of the neighbour search's cell) plus a halo: copies of the other ranks' particles
within the halo width (the lists' reach h (1 + skin); the grid's h) of the slab. The core does
the steps (scenes/sph/ranks.h: halo slots take part in every pair walk, add nothing to the
reductions and are not integrated); this module moves the data between the ranks with mpi4py
(numpy buffers on the host: on CUDA the slots are gathered on the device and staged through
host memory), so the compiled core never links MPI.

A step: (1) on a relisting (the `lists` index: when a particle of any rank has moved skin h / 2
since the last build; other indexes: every step) every rank sends each particle it owns to the
slab that holds it now and, as halo, to every other slab within the halo width (every moving
field travels: the Verlet history too), and uploads what it received (its counts change); on
the other steps every rank sends the new position, velocity and density of the particles that
are other ranks' halo, into the same slots. (2) The core's first half (sort, pair pass, probes,
reductions) gives the rank's sums; (3) every rank gathers all ranks' sums and the core's second
half combines them in rank order (the same global dt on every rank), finalizes and integrates.

The sort breaks ties within a cell by particle id (`sph.order_by_id`, forced on here), so every
particle's neighbours are walked in the order one process walks them: the run is bitwise the
one-process run with `sph.order_by_id = true` (tests/mpi/test_sph_ranks.py).

:class:`RankedCore` stands in for the compiled core behind :class:`corpuscle.Simulation`: its
downloads, views and checkpoints are the whole scene's in particle-id order (collectives: every
rank calls them in the same order, as every rank runs the same program), its scalars the
global ones (sums over the ranks, the probes from the rank that holds each).
"""

from __future__ import annotations

import math
import time as _time
from typing import Any

import numpy as np

# the kinds split over ranks (their pipeline has the ranks' API: scenes/sph/ranks.h)
RANK_KINDS = ("fluid-box", "fluid-box-2d", "dam-break", "dam-break-2d")

# the fields a particle carries to another rank (every field that moves with it)
MOVED = ("position", "velocity", "density", "id", "velocity_prev", "density_prev")
# what a halo copy needs each step (the pair pass reads these; the reorder derives the rest)
REFRESHED = ("position", "velocity", "density")

FLUID_GROUP_FIELDS = ("position", "velocity", "density", "id", "velocity_prev", "density_prev", "pressure",
                      "acceleration", "density_rate", "shift_grad", "halo")
WALL_FIELDS = {"wall_position": "position", "wall_id": "id", "wall_density": "density",
               "wall_density_prev": "density_prev", "wall_pressure": "pressure", "wall_velocity": "velocity"}

WALL_WEIGHT = 0.05  # a wall particle's share of a fluid particle's work in the first cuts
_BAD_NEIGHBORS = 2  # kBadNeighbors (scenes/sph/model.h): a list overflowed, grow and repeat


class RankError(ValueError):
    """A scene that cannot be split over these ranks (one line, exit code 2)."""

    exit_code = 2


def check_splittable(scene, size: int, neighbors: str | None) -> None:
    """One line when the scene cannot run over ``size`` ranks."""
    if scene.kind not in RANK_KINDS:
        raise RankError(f"scene kind {scene.kind!r} is not split over ranks yet (the SPH box kinds are: "
                        f"{', '.join(RANK_KINDS)}; docs/distributed.md)")
    bodies = scene.arrays.get("bodies", []) or []
    moving = [b for b in bodies if str(b.get("motion", "fixed")) not in ("fixed", "none", "")]
    if moving:
        raise RankError("bodies: moving bodies are not split over ranks yet (docs/distributed.md); "
                        "run this scene on one rank")
    if scene.values.get("sph.transport_velocity"):
        raise RankError("sph.transport_velocity = true: the transport velocity's stored push is not carried between "
                        "ranks yet (docs/distributed.md); run this scene on one rank")
    from . import kinds as _kinds

    kind = _kinds.find(scene.kind)
    periodic = list(scene.values.get("boundary.periodic", []) or [])
    if kind is not None and len(set(periodic)) >= kind.dim:
        raise RankError(f"boundary.periodic = {periodic}: every axis wraps; a scene split over ranks needs an axis "
                        "that does not (run it on one rank)")
    if neighbors not in (None, "lists", "grid"):
        raise RankError(f"--neighbors {neighbors}: a scene split over ranks runs the lists or the grid "
                        "(compact and allpairs run on one rank)")


class RankedCore:
    """The compiled core of one rank, and what the whole scene's ranks do together."""

    def __init__(self, comm, kind, built, backend: str, index: str, device: int, checkpoint: dict | None):
        from . import _core as core

        self.comm = comm
        self.rank, self.size = comm.Get_rank(), comm.Get_size()
        self.kind = kind
        self.index = index
        params = dict(built.params)
        params["order_by_id"] = 1
        self.D = D = kind.dim
        self.nf = int(params["n_fluid"])
        self.nw = int(params["n_wall"])
        self.n = self.nf + self.nw
        # the rank's core, made for its share of the fluid (what sizes its buffers at first and picks
        # the lists' lanes on CUDA, as a one-process run of that size would) and then given its
        # slots (set_counts)
        share = max(1, self.nf // comm.Get_size())
        rho0 = float(np.asarray(built.arrays["density"]).reshape(-1)[0]) if self.nf else 1000.0
        start = {"position": np.zeros((share, D), np.float32), "velocity": np.zeros((share, D), np.float32),
                 "density": np.full(share, rho0, np.float32),
                 "wall_position": np.zeros((0, D), np.float32), "wall_density": np.zeros(0, np.float32)}
        self.raw = core.Simulation(kind.name, backend, index, dict(params, n_fluid=share, n_wall=0), start, device)
        self._snapshot: dict[str, Any] | None = None
        self._override: dict[str, Any] = {}
        # the decomposition: slabs along the longest axis that does not wrap
        lo = np.asarray(params["domain_lo"], dtype=np.float64)
        hi = np.asarray(params["domain_hi"], dtype=np.float64)
        periodic = int(params.get("periodic", 0))
        axes = [k for k in range(D) if not periodic & (1 << k)]
        if not axes:
            raise RankError("boundary.periodic: every axis wraps; a scene split over ranks needs one that does not")
        self.axis = max(axes, key=lambda k: hi[k] - lo[k])
        reach = float(params["list_radius"]) if index == "lists" else float(params["h"])
        self.width = reach * (1.0 + 1e-5)  # the halo's width (a margin for float positions)
        self.cell = reach
        self.lo, self.hi = float(lo[self.axis]), float(hi[self.axis])
        ncell = max(1, int(math.floor((self.hi - self.lo) / self.cell)))
        if ncell < self.size:
            raise RankError(f"the domain is {ncell} cells of {self.cell:.4g} m along {'xyz'[self.axis]}, fewer than "
                            f"the {self.size} ranks: use fewer ranks or a smaller spacing")
        self.ncell = ncell
        self.relists_always = index != "lists"
        self.maps_stale = True
        # load balancing (run.rebalance: max / mean of the ranks' core time since the last
        # balance above which the cuts move; 0: never)
        self.rebalance = float(built.params.get("rebalance", 0.0) or 0.0)
        self.rebalances = 0
        self._balanced_at = 0.0
        self.params = params
        self.outside_max = 0
        self.outside = 0
        self.bad = 0
        self.bad_step = -1
        self.step_seconds = 0.0  # this rank's time in the core's halves (the load balance)
        self.exchange_seconds = 0.0
        self.migrations = 0
        # the whole scene in id order (fluid ids 0 .. nf - 1, walls nf .. n - 1)
        whole = self._whole_from_build(built.arrays) if checkpoint is None else self._whole_from_checkpoint(checkpoint)
        # at first the fluid splits evenly (a wall particle's work is a small part of a fluid one's:
        # it lists and sums the fluid only)
        self.cuts = self._balanced_cuts(whole["position"][:, self.axis],
                                        np.where(whole["id"] < self.nf, 1.0, WALL_WEIGHT))
        self._place(whole)
        if checkpoint is not None:
            self._restore_scalars(checkpoint)
        # the probes: each read on the rank whose slab and halo hold its support
        self.probe_owner = []
        self.probe_owner = self._probe_owners(params)

    # ---- the whole scene and its decomposition ------------------------------------------
    def _whole_from_build(self, arrays) -> dict[str, np.ndarray]:
        D, nf, nw = self.D, self.nf, self.nw
        pos = np.concatenate([np.asarray(arrays["position"], np.float32).reshape(-1, D),
                              np.asarray(arrays["wall_position"], np.float32).reshape(-1, D)])
        wv = arrays.get("wall_velocity")
        wall_vel = np.zeros((nw, D), np.float32) if wv is None else np.asarray(wv, np.float32).reshape(-1, D)
        vel = np.concatenate([np.asarray(arrays["velocity"], np.float32).reshape(-1, D), wall_vel])
        rho = np.concatenate([np.asarray(arrays["density"], np.float32).reshape(-1),
                              np.asarray(arrays["wall_density"], np.float32).reshape(-1)])
        return {"position": pos, "velocity": vel, "density": rho, "id": np.arange(nf + nw, dtype=np.int32),
                "velocity_prev": vel.copy(), "density_prev": rho.copy()}

    def _whole_from_checkpoint(self, state) -> dict[str, np.ndarray]:
        D, nf, nw = self.D, self.nf, self.nw
        fid = np.asarray(state["id"]).reshape(-1)
        wid = np.asarray(state["wall_id"]).reshape(-1) if "wall_id" in state else np.arange(nf, nf + nw)
        if fid.shape != (nf,) or np.any(np.sort(fid) != np.arange(nf)):
            raise ValueError(f"checkpoint id must be a permutation of 0..{nf - 1}")
        if wid.shape != (nw,) or np.any(np.sort(wid) != np.arange(nf, nf + nw)):
            raise ValueError(f"checkpoint wall_id must be a permutation of {nf}..{nf + nw - 1}")
        fo, wo = np.argsort(fid, kind="stable"), np.argsort(wid, kind="stable")

        def both(f, w, comps):
            a = np.asarray(state[f], np.float32).reshape(nf, comps) if comps > 1 else \
                np.asarray(state[f], np.float32).reshape(nf)
            if w in state:
                b = np.asarray(state[w], np.float32)
                b = b.reshape(nw, comps) if comps > 1 else b.reshape(nw)
            else:
                b = np.zeros((nw, comps) if comps > 1 else nw, np.float32)
            return np.concatenate([a[fo], b[wo]])

        pos = both("position", "wall_position", D)
        vel = both("velocity", "wall_velocity", D)
        vprev = both("velocity_prev", "wall_velocity", D)
        rho = both("density", "wall_density", 1)
        rprev = both("density_prev", "wall_density_prev", 1)
        return {"position": pos, "velocity": vel, "density": rho, "id": np.arange(nf + nw, dtype=np.int32),
                "velocity_prev": vprev, "density_prev": rprev}

    def _cells(self, x: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((x - self.lo) / self.cell).astype(np.int64), 0, self.ncell - 1)

    def _balanced_cuts(self, x: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
        """R - 1 cuts on cell boundaries that split the weight (default: the particles) evenly."""
        return self._cuts_of(np.bincount(self._cells(x), weights=weight, minlength=self.ncell).astype(np.float64))

    def _cuts_of(self, w: np.ndarray) -> np.ndarray:
        """R - 1 cuts on cell boundaries that split the cells' weights w evenly."""
        cum = np.cumsum(w)
        total = cum[-1] if cum.size else 0.0
        cuts, prev = [], 0
        for r in range(1, self.size):
            c = int(np.searchsorted(cum, total * r / self.size, side="left")) + 1  # cells [0, c) to ranks < r
            c = min(max(c, prev + 1), self.ncell - (self.size - r))  # every slab at least one cell
            cuts.append(c)
            prev = c
        return self.lo + self.cell * np.asarray(cuts, dtype=np.float64)

    def _owner(self, x: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.cuts, x, side="right")

    def _extent(self, r: int) -> tuple[float, float]:
        """Rank r's slab widened by the halo."""
        a = -math.inf if r == 0 else self.cuts[r - 1] - self.width
        b = math.inf if r == self.size - 1 else self.cuts[r] + self.width
        return a, b

    def _place(self, whole: dict[str, np.ndarray]) -> None:
        """This rank's particles (its slab's and its halo) out of the whole scene (every rank
        holds it: the halo maps need no messages)."""
        x = whole["position"][:, self.axis]
        owner = self._owner(x)
        a, b = self._extent(self.rank)
        own = owner == self.rank
        halo = (x >= a) & (x <= b) & ~own
        self._upload({k: v[own] for k, v in whole.items()}, {k: v[halo] for k, v in whole.items()})
        self.need_relist = False  # (the halo is current; the first step relists: set_counts)

    def _set_maps(self, own: dict[str, np.ndarray], halo: dict[str, np.ndarray]) -> None:
        """Which of my particles each rank holds as halo (send_ids) and which of my halo copies
        each rank owns (recv_ids), in id order: from the positions the migration placed them by
        (every rank decides a particle's owner and whether it lies in a slab's reach by the same
        test on the same numbers), so the lists agree without messages. A halo copy's owner is its
        owner now: a particle that just left my slab but stays within my reach came as my own
        copy, and its new owner refreshes it from the next step on."""
        xo, xh = own["position"][:, self.axis], halo["position"][:, self.axis]
        ho = self._owner(xh)
        self.recv_ids = [np.sort(halo["id"][ho == r]) for r in range(self.size)]
        self.send_ids = []
        for r in range(self.size):
            a, b = self._extent(r)
            self.send_ids.append(np.sort(own["id"][(xo >= a) & (xo <= b)]) if r != self.rank
                                 else np.zeros(0, np.int32))

    def _upload(self, own: dict[str, np.ndarray], halo: dict[str, np.ndarray]) -> None:
        """Give the core these slots: fluid (own, halo), walls (own, halo); every moved field."""
        nf = self.nf
        parts = []
        for src, flag in ((own, 0), (halo, 1)):
            ids = src["id"]
            parts.append((src, flag, ids < nf))
        order = []
        for wall in (False, True):
            for src, flag, fluid in parts:
                sel = ~fluid if wall else fluid
                order.append((src, flag, sel))
        fields = {}
        for f in MOVED:
            fields[f] = np.concatenate([src[f][sel] for src, _, sel in order])
        hflag = np.concatenate([np.full(int(sel.sum()), flag, np.int32) for _, flag, sel in order])
        n_fluid = int(sum(int(sel.sum()) for src, flag, sel in order[:2]))
        n_wall = int(len(hflag) - n_fluid)
        self.raw.set_counts(n_fluid, n_wall, self.n)
        slots = np.arange(n_fluid + n_wall, dtype=np.int32)
        for f in MOVED:
            self.raw.set_slots(f, slots, np.ascontiguousarray(fields[f]))
        self.raw.set_slots("halo", slots, hflag)
        self.n_own = int(len(own["id"]))
        self.n_own_fluid = int(np.count_nonzero(own["id"] < nf))
        self.n_halo = int(len(halo["id"]))
        self._set_maps(own, halo)
        self.maps_stale = True
        self._snapshot = None

    def _remap(self) -> None:
        """Slots of the ids in send_ids / recv_ids (the sort moved them)."""
        n = self.raw.slots()
        ids = self.raw.get_slots("id", np.arange(n, dtype=np.int32))
        slot_of = np.empty(self.n, dtype=np.int32)
        slot_of[ids] = np.arange(n, dtype=np.int32)
        self.send_slots = [np.ascontiguousarray(slot_of[s]).astype(np.int32) for s in self.send_ids]
        self.recv_slots = [np.ascontiguousarray(slot_of[s]).astype(np.int32) for s in self.recv_ids]
        self.maps_stale = False

    # ---- the exchanges --------------------------------------------------------------------
    def _migrate(self) -> None:
        """Every particle to the slab that holds it, and as halo to the slabs within reach."""
        t0 = _time.perf_counter()
        n = self.raw.slots()
        halo = self.raw.get_slots("halo", np.arange(n, dtype=np.int32))
        own = np.flatnonzero(halo == 0).astype(np.int32)
        data = {f: self.raw.get_slots(f, own) for f in MOVED}
        x = data["position"][:, self.axis]
        owner = self._owner(x)
        out = []
        for r in range(self.size):
            a, b = self._extent(r)
            to_own = owner == r
            to_halo = (x >= a) & (x <= b) & ~to_own
            out.append(({f: v[to_own] for f, v in data.items()}, {f: v[to_halo] for f, v in data.items()}))
        got = self.comm.alltoall(out)
        own_in = {f: np.concatenate([g[0][f] for g in got]) for f in MOVED}
        halo_in = {f: np.concatenate([g[1][f] for g in got]) for f in MOVED}
        self._upload(own_in, halo_in)
        self.migrations += 1
        self.exchange_seconds += _time.perf_counter() - t0

    def _refresh_halo(self) -> None:
        """The halo copies' new position, velocity and density from their owners, into their slots."""
        t0 = _time.perf_counter()
        if self.maps_stale:
            self._remap()
        out = [{f: self.raw.get_slots(f, s) for f in REFRESHED} if len(s) else None for s in self.send_slots]
        got = self.comm.alltoall(out)
        for r, g in enumerate(got):
            s = self.recv_slots[r]
            if g is None or not len(s):
                continue
            for f in REFRESHED:
                self.raw.set_slots(f, s, np.ascontiguousarray(g[f]))
        self.exchange_seconds += _time.perf_counter() - t0

    # ---- stepping -------------------------------------------------------------------------
    def _maybe_rebalance(self) -> None:
        """At a relisting: when the ranks' core time since the last balance is out of balance by
        more than run.rebalance (max / mean), new cuts that split the measured work evenly: each
        rank's time spread over its own particles, summed per cell over the ranks (in rank order:
        the same cuts on every rank). The physics does not depend on the cuts (bitwise), so only
        the time changes."""
        if self.rebalance <= 0.0 or self.size == 1:
            return
        spent = self.step_seconds - self._balanced_at
        n = self.raw.slots()
        slots = np.arange(n, dtype=np.int32)
        own = slots[self.raw.get_slots("halo", slots) == 0]
        x = self.raw.get_slots("position", own)[:, self.axis] if len(own) else np.zeros(0)
        cost = spent / len(own) if len(own) else 0.0
        rows = self.comm.allgather((spent, np.bincount(self._cells(x), minlength=self.ncell) * cost))
        t = [r[0] for r in rows]
        mean = sum(t) / len(t)
        if not (mean > 0.0 and max(t) / mean > self.rebalance):
            return
        w = np.zeros(self.ncell)
        for r in rows:
            w = w + r[1]
        cuts = self._cuts_of(w)
        if np.array_equal(cuts, self.cuts):
            return
        if self.probe_owner:
            # every rank's record takes the probes' readings and series of their holders, so the
            # new holder of a probe goes on from its holder's ring
            self._gather_probes()
            for name, _ in self._PROBE_KEYS + (("probe_series_time", 0), ("probe_series_pressure", 0)):
                self.raw.set_scalar(name, self._override[name])
        self.cuts = cuts
        self.probe_owner = self._probe_owners(self.params)
        self.rebalances += 1
        self._balanced_at = self.step_seconds

    def _one_step(self, relist: bool) -> bool:
        """One step of every rank; False when it was not taken (the end, or unsound)."""
        if relist:
            self._maybe_rebalance()
            self._migrate()
        else:
            self._refresh_halo()
        for _ in range(8):
            t0 = _time.perf_counter()
            sums, bad, relisting, _, _ = self.raw.step_half(0)
            self.step_seconds += _time.perf_counter() - t0
            if relisting:
                self.maps_stale = True  # (the step sorts: the halo's slots move)
            halves = self.comm.allgather((sums, int(bad)))
            if not any(b == _BAD_NEIGHBORS for _, b in halves):
                break
            # a rank's lists overflowed: it grows them and every rank runs the first half again
            if bad == _BAD_NEIGHBORS and not self.raw.step_half(2)[4]:
                raise MemoryError("the neighbour lists overflowed and cannot grow in this rank's memory")
            self._snapshot = None
        t0 = _time.perf_counter()
        _, bad, rebuild, outside, _ = self.raw.step_half(1, b"".join(h for h, _ in halves), self.size)
        self.step_seconds += _time.perf_counter() - t0
        flags = self.comm.allgather((int(bad), int(rebuild), int(outside)))
        self._snapshot = None
        self.outside = sum(f[2] for f in flags)
        self.outside_max = max(self.outside_max, self.outside)
        bads = [f[0] for f in flags if f[0]]
        if bads and not self.bad:
            self.bad = bads[0]
        self.need_relist = self.relists_always or any(f[1] for f in flags)
        return True

    def step(self, n: int) -> int:
        """Up to n steps of every rank (all stop together: the end time and the flags are global)."""
        one = self.raw.scalar_of_scenes  # (one value of the record: no dictionary of them all)
        first = int(one("step")[0])
        for _ in range(int(n)):
            if one("done")[0] or one("bad")[0] or self.bad:
                break
            self._one_step(self.need_relist)
        self._gather_probes()
        return int(one("step")[0]) - first

    # ---- the scalars -----------------------------------------------------------------------
    def _local(self) -> dict[str, Any]:
        if self._snapshot is None:
            self._snapshot = dict(self.raw.scalars())
        return self._snapshot

    def snapshot(self) -> dict[str, Any]:
        s = dict(self._local())
        s.update(self._override)
        s["outside"] = self.outside
        s["outside_max"] = self.outside_max
        s["n_fluid"] = float(self.nf)
        s["n_wall"] = float(self.nw)
        s["mean_neighbors"] = float(s["sums_nbrs"]) / self.nf if self.nf else 0.0
        if self.bad and not s["bad"]:
            s["bad"] = self.bad
            s["bad_step"] = s["step"]
        return s

    def scalars(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, list) else v for k, v in self.snapshot().items()}

    def invalidate(self) -> None:
        self._snapshot = None

    _PROBE_KEYS = (("probe_pressure", 1), ("probe_velocity", 3), ("probe_weight", 1), ("probe_series_count", 1))

    def _probe_owners(self, params) -> list[int]:
        D = self.D
        probes = np.asarray(params.get("probes", []), dtype=np.float64).reshape(-1, D)
        sizes = np.asarray(params.get("probe_size", [0.0] * len(probes)), dtype=np.float64).reshape(-1)
        h = float(params["h"])
        owners = []
        for k, p in enumerate(probes):
            half = 0.5 * float(sizes[k]) if k < len(sizes) else 0.0
            need = (p[self.axis] - half - h, p[self.axis] + half + h)
            for r in range(self.size):
                a, b = self._extent(r)
                if need[0] >= a and need[1] <= b:
                    owners.append(r)
                    break
            else:
                raise RankError(f"probes[{k}]: its face and kernel support span {2 * (half + h):.4g} m along "
                                f"{'xyz'[self.axis]}, more than one slab with its halo holds: use fewer ranks")
        return owners

    def _gather_probes(self) -> None:
        """Each probe's reading and series from the rank that holds it (every rank's core reads
        every probe; only the holder's reading has all the fluid around it)."""
        if not self.probe_owner:
            return
        s = self._local()
        mine = {}
        for k, r in enumerate(self.probe_owner):
            if r != self.rank:
                continue
            mine[k] = {name: list(s[name][c * k:c * (k + 1)]) for name, c in self._PROBE_KEYS}
            mine[k]["probe_series_time"] = list(s["probe_series_time"][32 * k:32 * (k + 1)])
            mine[k]["probe_series_pressure"] = list(s["probe_series_pressure"][32 * k:32 * (k + 1)])
        every = self.comm.allgather(mine)
        over = {name: list(s[name]) for name, _ in self._PROBE_KEYS}
        over["probe_series_time"] = list(s["probe_series_time"])
        over["probe_series_pressure"] = list(s["probe_series_pressure"])
        for part in every:
            for k, vals in part.items():
                for name, c in self._PROBE_KEYS:
                    over[name][c * k:c * (k + 1)] = vals[name]
                over["probe_series_time"][32 * k:32 * (k + 1)] = vals["probe_series_time"]
                over["probe_series_pressure"][32 * k:32 * (k + 1)] = vals["probe_series_pressure"]
        self._override.update(over)

    # ---- the whole scene's arrays (collectives) ---------------------------------------------
    def _gathered(self, field: str, walls: bool) -> np.ndarray:
        n = self.raw.slots()
        slots = np.arange(n, dtype=np.int32)
        halo = self.raw.get_slots("halo", slots)
        ids = self.raw.get_slots("id", slots)
        keep = (halo == 0) & ((ids >= self.nf) if walls else (ids < self.nf))
        sel = slots[keep]
        vals = self.raw.get_slots(field, sel) if field != "id" else ids[keep]
        parts = self.comm.allgather((ids[keep], vals))
        allids = np.concatenate([p[0] for p in parts])
        allvals = np.concatenate([p[1] for p in parts])
        out = np.empty_like(allvals)
        out[allids - (self.nf if walls else 0)] = allvals
        return out

    def download(self, name: str) -> np.ndarray:
        if name in WALL_FIELDS:
            return self._gathered(WALL_FIELDS[name], True)
        return self._gathered(name, False)

    def view(self, name: str) -> np.ndarray:
        return self.download(name)

    def download_many(self, names) -> dict[str, np.ndarray]:
        return {n: self.download(n) for n in names}

    @property
    def n_particles(self) -> int:
        return self.nf

    def fields(self):
        return [f for f in self.raw.fields() if f["name"] != "halo"]

    def controls(self):
        return self.raw.controls()

    def scalar_of_scenes(self, name):
        return self.raw.scalar_of_scenes(name)

    def set_end_time(self, t: float) -> None:
        self.raw.set_end_time(t)
        self._snapshot = None

    def set_control(self, values) -> None:
        self.raw.set_control(values)

    def evaluate(self) -> None:
        """The state's densities, pressures and sums (combined over the ranks into the record)."""
        if self.need_relist:
            self._migrate()
        else:
            self._refresh_halo()
        self.need_relist = True  # (the evaluation sorted: the next step relists, as one process's)
        self.raw.evaluate()
        self._snapshot = None
        s = self._local()
        mine = [s[k] for k in ("sums_amax2", "sums_vmax2", "sums_mu_max", "sums_ke", "sums_rho_min", "sums_rho_max",
                               "sums_p_max", "sums_nbrs")]
        every = self.comm.allgather(mine)
        f32 = np.float32
        amax2 = max(f32(e[0]) for e in every)
        vmax2 = max(f32(e[1]) for e in every)
        mu = max(f32(e[2]) for e in every)
        ke = f32(0.0)
        for e in every:
            ke = f32(ke + f32(e[3]))
        out = {"sums_amax2": float(amax2), "sums_vmax2": float(vmax2), "sums_mu_max": float(mu), "sums_ke": float(ke),
               "sums_rho_min": float(min(f32(e[4]) for e in every)), "sums_rho_max": float(max(f32(e[5]) for e in every)),
               "sums_p_max": float(max(f32(e[6]) for e in every)), "sums_nbrs": int(sum(int(e[7]) for e in every))}
        for k, v in out.items():
            self.raw.set_scalar(k, v)
        self._snapshot = None
        self._gather_probes()

    def checkpoint(self) -> dict:
        """The whole state as one process's checkpoint reads (particles in id order)."""
        local = dict(self.raw.checkpoint())
        self.need_relist = True  # the next step relists, as after one process's checkpoint
        out = {k: v for k, v in local.items() if not hasattr(v, "shape") or k.startswith("control_")}
        for f in ("position", "velocity", "density", "id", "velocity_prev", "density_prev"):
            out[f] = self._gathered(f, False)
        for w, f in (("wall_position", "position"), ("wall_id", "id"), ("wall_density", "density"),
                     ("wall_density_prev", "density_prev")):
            out[w] = self._gathered(f, True)
        out["outside"] = self.outside
        out["outside_max"] = self.outside_max
        for f in self.raw.fields():  # a field of its own group that ranks refuse (the transport velocity's): empty
            if f["checkpointed"] and f["name"] not in out:
                out[f["name"]] = local[f["name"]]
        return out

    def restore(self, full: dict) -> None:
        whole = self._whole_from_checkpoint(full)
        self._place(whole)
        self._restore_scalars(full)
        self.need_relist = True

    def _restore_scalars(self, full: dict) -> None:
        """The checkpoint's record scalars into every rank's record (the fields are placed)."""
        # the core's restore wants fields of its counts: give it its own, then put the slots back
        n = self.raw.slots()
        slots = np.arange(n, dtype=np.int32)
        keep = {f: self.raw.get_slots(f, slots) for f in MOVED + ("halo",)}
        ids = keep["id"]
        nf_local = int(np.count_nonzero(ids < self.nf))
        names = {f["name"] for f in self.raw.fields()}
        state = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in full.items() if k not in names}
        for f in self.raw.fields():
            if not f["checkpointed"]:
                continue
            name = f["name"]
            base = WALL_FIELDS.get(name, name)
            if base not in keep:  # a field of its own group that ranks refuse (the transport velocity's): empty
                comps = int(f["components"])
                state[name] = np.zeros((0, comps) if comps > 1 else (0,), dtype=np.dtype(f["dtype"]))
                continue
            part = keep[base][nf_local:] if name in WALL_FIELDS else keep[base][:nf_local]
            if name == "wall_id":
                part = np.arange(nf_local, n, dtype=np.int32)
            elif name == "id":
                part = np.arange(nf_local, dtype=np.int32)
            state[name] = np.ascontiguousarray(part)
        self.raw.restore(state)
        for f in MOVED + ("halo",):
            self.raw.set_slots(f, slots, np.ascontiguousarray(keep[f]))
        self.outside = int(full.get("outside", 0))
        self.outside_max = int(full.get("outside_max", 0))
        self._snapshot = None

    def bench(self, n):
        t0 = _time.perf_counter()
        self.step(n)
        return _time.perf_counter() - t0

    def balance(self) -> dict[str, Any]:
        """Per-rank work: owned particles, halo, seconds in the core; max / mean of the core time."""
        rows = self.comm.allgather((self.n_own, self.n_halo, self.step_seconds, self.exchange_seconds))
        t = [r[2] for r in rows]
        mean = sum(t) / len(t) if t else 0.0
        return {"ranks": self.size, "axis": "xyz"[self.axis], "owned": [r[0] for r in rows],
                "halo": [r[1] for r in rows], "core_seconds": t, "exchange_seconds": [r[3] for r in rows],
                "imbalance": (max(t) / mean) if mean > 0 else 1.0, "migrations": self.migrations,
                "rebalances": self.rebalances, "cuts": [float(c) for c in self.cuts]}


def ranked_simulation(scene, backend: str, comm, checkpoint: dict | None = None, neighbors: str | None = None,
                      device: int | None = None):
    """A :class:`corpuscle.Simulation` of ``scene`` split over ``comm``'s ranks (collective:
    every rank calls it with the same arguments). CUDA: each rank drives the GPU of its
    node-local rank (modulo the node's GPUs; ranks share a GPU when there are fewer)."""
    from . import kinds as _kinds
    from .kinds import Target
    from .simulation import BackendError, Simulation, _check_state, _core, resolve_backend

    check_splittable(scene, comm.Get_size(), neighbors)
    if not scene.values.get("sph.order_by_id", False):
        scene = scene.with_overrides({"sph.order_by_id": True})  # (the header records it: a resume on one
        #                                                          rank sorts as these ranks do)
    if checkpoint is not None:
        _check_state(checkpoint)
    sim = Simulation.__new__(Simulation)
    sim.scene = scene
    sim.backend = resolve_backend(backend)
    kinds = dict(_core().kinds(hidden=True))
    kind = _kinds.find(scene.kind)
    if scene.kind not in kinds or kind is None:
        raise BackendError(f"scene kind {scene.kind!r} is not supported by this version")
    sim.kind = kind
    sim.neighbors = kinds[scene.kind][0] if neighbors is None else str(neighbors)
    if sim.neighbors not in kinds[scene.kind]:
        raise ValueError(f"--neighbors must be one of {', '.join(kinds[scene.kind])} (the indexes of {scene.kind}), "
                         f"got {sim.neighbors!r}")
    if device is None:
        device = 0
        if sim.backend == "cuda":
            from . import _mpi
            local, _ = _mpi.node_local_rank(comm)
            gpus = len(_core().build_info().get("gpus") or [None])
            device = local % max(1, gpus)
    sim.device = int(device)
    t0 = _time.perf_counter()
    built = kind.build(scene, Target(sim.backend, sim.neighbors, sim.device), checkpoint)
    sim.params = built.params
    sim.info = dict(built.info)
    sim.end_time = float(scene.values["run.end_time"])
    sim.core = RankedCore(comm, kind, built, sim.backend, sim.neighbors, sim.device, checkpoint)
    sim._fields = [dict(f) for f in sim.core.fields()]
    sim._control = {str(k): [0.0] * int(v) for k, v in dict(sim.core.controls()).items()}
    if checkpoint is None:
        sim.core.evaluate()
    else:
        for name in sim._control:
            given = checkpoint.get(f"control_{name}", [0.0] * len(sim._control[name]))
            sim._control[name] = [float(x) for x in np.atleast_1d(np.asarray(given, dtype=np.float64))]
    sim.init_seconds = _time.perf_counter() - t0
    sim.ranks = comm.Get_size()
    return sim
