"""The spatial index plug-ins (cpp/include/corpuscle/spatial/) through corpuscle._testing:
Morton codes, and every index (all pairs, tiled all pairs, the per-axis cell grid, CSR lists
built from the grid or from all pairs) against a NumPy brute force, in 2-D and 3-D, on every
backend (``cuda``: ``gpu`` mark, skipped cleanly without a usable device).

On the CPU the brute force repeats the C++ arithmetic in float32 (d = xi - xj, r2 summed
axis by axis), so the sets must match exactly; CUDA may contract r2 into FMAs, so there
pairs within a relative 1e-5 of the radius may go either way.
"""

import hashlib

import numpy as np
import pytest

from corpuscle import _testing as T

CUDA, CUDA_WHY = T.cuda_available()
requires_cuda = pytest.mark.skipif(not CUDA, reason=f"no usable CUDA backend: {CUDA_WHY}")

# (*_rows: the grid kinds with their cells sorted in rows, as the SPH scenes sort them)
INDEXES = ["allpairs", "allpairs_tiled", "grid", "csr_grid", "csr_allpairs", "grid_rows", "csr_grid_rows"]
GRID_INDEXES = ["grid", "csr_grid", "grid_rows", "csr_grid_rows"]


# --------------------------------------------------------------------------------------
# brute force
# --------------------------------------------------------------------------------------
def r2_matrix(pos):
    """float32 r2[i, j] computed like the C++ views (d = xi - xj, then d0^2 + d1^2 (+ d2^2))."""
    pos = np.asarray(pos, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        r2 = np.zeros((len(pos), len(pos)), np.float32)
        for k in range(pos.shape[1]):
            d = pos[:, None, k] - pos[None, :, k]
            r2 = r2 + d * d if k else d * d
    return r2


_BRUTE = {}


def brute_codes(pos, radius, tags=None, tag_mode="all", tag_range=(0, 1), ntags=1):
    """(want, free) as sorted i * n + j codes: want = j is i's neighbour by the float32
    arithmetic; free = the pair lies so close to the radius that FMA rounding may move it
    either way (cached: the backends and indexes of one scene share them)."""
    key = (hashlib.sha1(np.ascontiguousarray(pos).tobytes()).hexdigest(), float(radius),
           None if tags is None else hashlib.sha1(np.asarray(tags).tobytes()).hexdigest(), tag_mode,
           tuple(tag_range), ntags)
    if key not in _BRUTE:
        if len(_BRUTE) > 64:
            _BRUTE.clear()
        sure, maybe = _brute_mask(pos, radius, tags, tag_mode, tag_range, ntags)
        _BRUTE[key] = (np.flatnonzero(sure.ravel()), np.flatnonzero(maybe.ravel()))
    return _BRUTE[key]


def _brute_mask(pos, radius, tags, tag_mode, tag_range, ntags):
    r2 = r2_matrix(pos)
    rr = np.float32(radius) * np.float32(radius)
    with np.errstate(invalid="ignore"):
        sure = r2 < rr
        maybe = np.abs(r2.astype(np.float64) - float(rr)) <= 1e-5 * float(rr)
    if tags is not None:
        tags = np.asarray(tags)
        valid = (tags >= 0) & (tags < ntags)
        ok = valid[:, None] & valid[None, :]
        if tag_mode == "own":
            ok &= tags[:, None] == tags[None, :]
        elif tag_mode == "range":
            a, b = tag_range
            ok &= ((tags >= a) & (tags < b))[None, :]
        sure &= ok
        maybe &= ok
    return sure, maybe


def pair_codes(offsets, nbr, n):
    """Encode a CSR result as sorted i * n + j codes (plus the raw codes, to look for repeats)."""
    i = np.repeat(np.arange(n, dtype=np.int64), np.diff(offsets))
    codes = i * n + nbr.astype(np.int64)
    return codes


def assert_same_neighbours(res, pos, radius, exact, **tagargs):
    n = len(pos)
    offsets, nbr = res["offsets"], res["neighbors"]
    assert offsets.shape == (n + 1,) and offsets[0] == 0 and offsets[-1] == len(nbr)
    assert np.all(np.diff(offsets) >= 0)
    codes = pair_codes(offsets, nbr, n)
    assert len(np.unique(codes)) == len(codes), "a neighbour visited twice"
    want, free = brute_codes(pos, radius, **tagargs)
    got = np.sort(codes)
    if exact:
        np.testing.assert_array_equal(got, want)
    else:
        np.testing.assert_array_equal(np.setdiff1d(got, free), np.setdiff1d(want, free))


def assert_pairs_once(pairs, pos, radius, exact, **tagargs):
    n = len(pos)
    assert pairs.ndim == 2 and pairs.shape[1] == 2
    assert np.all(pairs[:, 0] != pairs[:, 1]), "pairs() visited a particle with itself"
    lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    codes = lo.astype(np.int64) * n + hi
    assert len(np.unique(codes)) == len(codes), "a pair visited twice"
    want, free = brute_codes(pos, radius, **tagargs)
    want, free = want[want // n < want % n], free[free // n < free % n]  # i < j
    got = np.sort(codes)
    if exact:
        np.testing.assert_array_equal(got, want)
    else:
        np.testing.assert_array_equal(np.setdiff1d(got, free), np.setdiff1d(want, free))


# --------------------------------------------------------------------------------------
# scenes of particles
# --------------------------------------------------------------------------------------
def uniform_box(dim, n=800, seed=0):
    rng = np.random.default_rng(seed)
    pos = rng.random((n, dim), dtype=np.float32)
    return pos, [0.0] * dim, [1.0] * dim, 0.12 if dim == 3 else 0.06


def elongated(dim, n=1000, seed=1):
    """A 4 x 0.25 (x 0.25) channel, cells many more along x than across."""
    rng = np.random.default_rng(seed)
    ext = np.array([4.0, 0.25, 0.25][:dim], dtype=np.float32)
    pos = (rng.random((n, dim), dtype=np.float32) * ext).astype(np.float32)
    return pos, [0.0] * dim, ext.tolist(), 0.06 if dim == 3 else 0.03


def outside(dim, n=800, seed=2):
    """A quarter of the particles outside the grid: next to it, far away, on every side."""
    rng = np.random.default_rng(seed)
    pos = rng.random((n, dim), dtype=np.float32)
    k = n // 4
    pos[:k] = rng.uniform(-0.6, 1.6, (k, dim)).astype(np.float32)
    pos[k : k + 20] = rng.uniform(-1e4, 1e4, (20, dim)).astype(np.float32)
    pos[k + 20 : k + 30] = pos[k : k + 10] + np.float32(0.01)  # neighbours far outside too
    return pos, [0.0] * dim, [1.0] * dim, 0.12 if dim == 3 else 0.06


def coincident(dim, seed=3):
    """Many particles sharing a handful of positions (r2 = 0 for all of them)."""
    rng = np.random.default_rng(seed)
    base = rng.random((12, dim), dtype=np.float32)
    pos = np.repeat(base, 40, axis=0)
    pos = np.concatenate([pos, rng.random((300, dim), dtype=np.float32)])
    rng.shuffle(pos)
    return pos.astype(np.float32), [0.0] * dim, [1.0] * dim, 0.05


def radius_beyond_domain(dim, n=400, seed=4):
    """A radius three times the domain: everybody neighbours everybody."""
    rng = np.random.default_rng(seed)
    pos = rng.random((n, dim), dtype=np.float32) * np.float32(0.5)
    return pos, [0.0] * dim, [0.5] * dim, 1.5


SCENES = {
    "uniform": uniform_box,
    "elongated": elongated,
    "outside": outside,
    "coincident": coincident,
    "radius_beyond_domain": radius_beyond_domain,
}


def run_gather(backend, index, scene, dim, list_skin=1.25, **kw):
    pos, lo, hi, radius = SCENES[scene](dim)
    res = T.gather(backend, index, pos, radius, lo=lo, hi=hi, list_radius=radius * list_skin, **kw)
    return res, pos, radius


# --------------------------------------------------------------------------------------
# Morton codes
# --------------------------------------------------------------------------------------
def interleave(coords, bits):
    """Reference Morton code: bit b of axis k goes to bit b * D + k."""
    coords = np.asarray(coords, dtype=np.uint64)
    dim = coords.shape[1]
    out = np.zeros(len(coords), dtype=np.uint64)
    for b in range(bits):
        for k in range(dim):
            out |= ((coords[:, k] >> np.uint64(b)) & np.uint64(1)) << np.uint64(b * dim + k)
    return out


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("wide", [False, True], ids=["32bit", "64bit"])
def test_morton_encode_matches_bit_interleave_and_decode_round_trips(dim, wide):
    bits = T.morton_max_bits(dim, wide)
    assert bits == {(2, False): 15, (3, False): 10, (2, True): 32, (3, True): 21}[(dim, wide)]
    rng = np.random.default_rng(dim + 10 * wide)
    top = min(2**bits, 2**31)
    coords = rng.integers(0, top, (5000, dim)).astype(np.int32)
    coords[:4] = 0
    coords[4, :] = top - 1  # every bit set
    codes = T.morton_encode(coords, wide)
    np.testing.assert_array_equal(codes, interleave(coords, bits))
    np.testing.assert_array_equal(T.morton_decode(codes, dim, wide), coords)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("wide", [False, True], ids=["32bit", "64bit"])
def test_morton_order_is_z_order_and_monotone_along_each_axis(dim, wide):
    # the unit Z: x fastest, then y, then z
    corners = np.array([[(c >> k) & 1 for k in range(dim)] for c in range(2**dim)], dtype=np.int32)
    np.testing.assert_array_equal(T.morton_encode(corners, wide), np.arange(2**dim))
    # moving one cell up along any axis (others fixed) increases the code
    rng = np.random.default_rng(7)
    c = rng.integers(0, 2**9, (2000, dim)).astype(np.int32)
    base = T.morton_encode(c, wide)
    for k in range(dim):
        up = c.copy()
        up[:, k] += 1
        assert np.all(T.morton_encode(up, wide) > base)
    # a block of 2^b cells per axis aligned at the origin covers codes [0, 2^(b*D)) exactly
    g = np.stack(np.meshgrid(*[np.arange(8)] * dim, indexing="ij"), -1).reshape(-1, dim).astype(np.int32)
    np.testing.assert_array_equal(np.sort(T.morton_encode(g, wide)), np.arange(8**dim))


# --------------------------------------------------------------------------------------
# the cell grid's shape
# --------------------------------------------------------------------------------------
def test_cell_grid_dims_follow_the_domain_per_axis():
    g = T.cell_grid_spec(3, [0, 0, 0], [4, 1, 1], 0.01)
    assert g["dims"] == [400, 100, 100]
    assert g["ncells"] == 400 * 100 * 100 == g["table_entries"]
    assert np.float32(0.01) * (1 + 1e-6) <= g["cell"] < np.float32(0.01) * (1 + 2e-6)
    # the Morton key needs bits for the longest axis only (2^9 >= 400); the tag sits above
    assert g["bits"] == 9 and g["tag_shift"] == 27 and g["key_bits"] == 28
    # memory is proportional to the domain: twice as long, twice the cells
    g2 = T.cell_grid_spec(3, [0, 0, 0], [8, 1, 1], 0.01)
    assert g2["ncells"] == 2 * g["ncells"]
    # 2-D, and tags multiply the table (not the cells)
    g3 = T.cell_grid_spec(2, [-1, 0], [1, 0.5], 0.1, ntags=3)
    assert g3["dims"] == [20, 5] and g3["ncells"] == 100 and g3["table_entries"] == 300
    assert g3["key_bits"] == 2 * 5 + 2


def test_cell_grid_with_radius_beyond_the_domain_has_one_cell_per_axis():
    g = T.cell_grid_spec(3, [0, 0, 0], [0.5, 0.5, 0.5], 2.0)
    assert g["dims"] == [1, 1, 1] and g["ncells"] == 1
    g = T.cell_grid_spec(2, [0, 0], [0, 0], 1.0)  # a degenerate (flat) domain is one cell too
    assert g["dims"] == [1, 1]


def test_cell_grid_refuses_more_cells_than_the_limit():
    with pytest.raises(ValueError, match=r"3000 x 1000 x 1000 cells.*more than the limit"):
        T.cell_grid_spec(3, [0, 0, 0], [30, 10, 10], 0.01)
    with pytest.raises(ValueError, match="more than the limit of 1000"):
        T.cell_grid_spec(2, [0, 0], [1, 1], 0.01, max_cells=1000)
    with pytest.raises(ValueError, match="for 4 tags"):
        T.cell_grid_spec(2, [0, 0], [1, 1], 0.01, ntags=4, max_cells=30000)
    with pytest.raises(ValueError, match="radius must be positive"):
        T.cell_grid_spec(3, [0, 0, 0], [1, 1, 1], 0.0)
    with pytest.raises(ValueError, match="upper corner"):
        T.cell_grid_spec(3, [0, 0, 0], [1, -1, 1], 0.1)
    with pytest.raises(ValueError, match="more than a 64-bit key holds"):
        T.cell_grid_spec(3, [0, 0, 0], [3e6, 1, 1], 1.0)  # 3e6 cells along x: 22 bits per axis


@pytest.mark.parametrize("dim", [2, 3])
def test_grid_keys_hold_tag_above_morton_cell_and_sort_stably_with_unused_slots_last(backend, dim):
    rng = np.random.default_rng(5)
    n = 3000
    pos = rng.uniform(-0.2, 1.2, (n, dim)).astype(np.float32)
    pos[:500] = pos[500:1000]  # equal keys: the sort must keep input order among them
    tags = rng.integers(-1, 3, n).astype(np.int32)  # -1: unused slot
    radius = 0.1
    spec = T.cell_grid_spec(dim, [0.0] * dim, [1.0] * dim, radius, ntags=3)
    keys, order = T.grid_sort(backend, pos, radius, [0.0] * dim, [1.0] * dim, tags=tags, ntags=3)
    assert sorted(order.tolist()) == list(range(n))
    # reference keys: clamped cells, 64-bit Morton, tag above
    cell = np.floor(pos.astype(np.float64) * (1.0 / spec["cell"]))  # the grid's cells are computed in double
    cell = np.clip(cell, 0, np.array(spec["dims"]) - 1).astype(np.int32)
    ref = T.morton_encode(cell, True) | (tags.astype(np.uint64) << np.uint64(spec["tag_shift"]))
    ref[tags < 0] = np.uint64(spec["sentinel"])
    np.testing.assert_array_equal(keys, ref[order])
    # stable sort by key: np's stable argsort gives the same order
    np.testing.assert_array_equal(order, np.argsort(ref, kind="stable"))
    # tags contiguous and ascending, unused slots at the end
    used = (tags >= 0).sum()
    assert np.all(keys[used:] == np.uint64(spec["sentinel"]))
    ktags = keys[:used] >> np.uint64(spec["tag_shift"])
    assert np.all(np.diff(ktags.astype(np.int64)) >= 0)


@pytest.mark.parametrize("dim", [2, 3])
def test_grid_keys_in_rows_hold_tag_above_the_linear_cell_and_need_no_more_bits_than_morton(backend, dim):
    rng = np.random.default_rng(6)
    n = 3000
    hi = [1.0, 0.7, 0.4][:dim]  # unequal axes: the linear index needs fewer bits than Morton's D * bits
    pos = (rng.uniform(-0.2, 1.2, (n, dim)) * np.array(hi)).astype(np.float32)
    pos[:500] = pos[500:1000]
    tags = rng.integers(-1, 3, n).astype(np.int32)
    radius = 0.05
    spec = T.cell_grid_spec(dim, [0.0] * dim, hi, radius, ntags=3, order="rows")
    morton = T.cell_grid_spec(dim, [0.0] * dim, hi, radius, ntags=3)
    assert spec["dims"] == morton["dims"] and spec["table_entries"] == morton["table_entries"]
    assert spec["cell_bits"] == int(np.ceil(np.log2(spec["ncells"]))) == spec["tag_shift"]
    assert spec["key_bits"] == spec["cell_bits"] + 2 < morton["key_bits"]
    keys, order = T.grid_sort(backend, pos, radius, [0.0] * dim, hi, tags=tags, ntags=3, order="rows")
    dims = np.array(spec["dims"])
    cell = np.floor(pos.astype(np.float64) * (1.0 / spec["cell"]))
    cell = np.clip(cell, 0, dims - 1).astype(np.uint64)
    linear = cell[:, 0] + np.uint64(dims[0]) * cell[:, 1]
    if dim == 3:
        linear += np.uint64(dims[0] * dims[1]) * cell[:, 2]
    ref = linear | (tags.astype(np.uint64) << np.uint64(spec["tag_shift"]))
    ref[tags < 0] = np.uint64(spec["sentinel"])
    np.testing.assert_array_equal(order, np.argsort(ref, kind="stable"))
    np.testing.assert_array_equal(keys, ref[order])
    with pytest.raises(ValueError, match="morton or rows"):
        T.cell_grid_spec(dim, [0.0] * dim, hi, radius, order="hilbert")


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scene", ["uniform", "outside", "elongated"])
@pytest.mark.parametrize("kind", ["grid", "csr_grid"])
def test_cells_in_rows_give_the_morton_grid_lists_entry_for_entry(backend, dim, scene, kind):
    # a row's three cells read as one range are the same slots in the same order as the three
    # cells one by one, and within a cell the stable sort keeps the input order in either
    # cell order: so in input numbering the lists are identical, entry for entry
    a, _, _ = run_gather(backend, kind, scene, dim)
    b, _, _ = run_gather(backend, kind + "_rows", scene, dim)
    np.testing.assert_array_equal(a["offsets"], b["offsets"])
    np.testing.assert_array_equal(a["neighbors"], b["neighbors"])


@pytest.mark.parametrize("width", ["narrow", "wide"])
def test_grid_keys_sort_the_same_stored_in_32_or_64_bits(backend, width):
    # keys of at most 32 bits are sorted as 32-bit words, wider ones as 64-bit: both give the
    # reference keys (tag above the Morton cell, unused slots as the sentinel) in stable order
    rng = np.random.default_rng(11)
    n = 4000
    hi = [1.0, 1.0, 1.0] if width == "narrow" else [3000.0, 1.0, 1.0]  # 3,000 cells along x: 12 bits an axis
    radius = 0.05 if width == "narrow" else 1.0
    pos = (rng.uniform(-0.1, 1.1, (n, 3)) * np.array(hi)).astype(np.float32)
    pos[:700] = pos[700:1400]
    tags = rng.integers(-1, 3, n).astype(np.int32)
    spec = T.cell_grid_spec(3, [0.0] * 3, hi, radius, ntags=3)
    assert (spec["key_bits"] <= 32) == (width == "narrow")
    keys, order = T.grid_sort(backend, pos, radius, [0.0] * 3, hi, tags=tags, ntags=3)
    cell = np.floor(pos.astype(np.float64) * (1.0 / spec["cell"]))
    cell = np.clip(cell, 0, np.array(spec["dims"]) - 1).astype(np.int32)
    ref = T.morton_encode(cell, True) | (tags.astype(np.uint64) << np.uint64(spec["tag_shift"]))
    ref[tags < 0] = np.uint64(spec["sentinel"])
    np.testing.assert_array_equal(order, np.argsort(ref, kind="stable"))
    np.testing.assert_array_equal(keys, ref[order])


# --------------------------------------------------------------------------------------
# every index finds what brute force finds
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("index", INDEXES)
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scene", list(SCENES))
def test_gather_finds_exactly_the_brute_force_neighbours(backend, index, dim, scene):
    res, pos, radius = run_gather(backend, index, scene, dim)
    assert_same_neighbours(res, pos, radius, exact=backend != "cuda")


@pytest.mark.parametrize("index", ["allpairs", "grid", "csr_grid", "csr_allpairs", "grid_rows", "csr_grid_rows"])  # tiled: gather only
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scene", ["uniform", "outside", "coincident", "radius_beyond_domain"])
def test_pairs_visits_each_unordered_pair_exactly_once(backend, index, dim, scene):
    pos, lo, hi, radius = SCENES[scene](dim)
    pairs = T.pairs(backend, index, pos, radius, lo=lo, hi=hi, list_radius=radius * 1.25)
    assert_pairs_once(pairs, pos, radius, exact=backend != "cuda")


@pytest.mark.parametrize("index", INDEXES)
def test_gather_order_is_deterministic_and_the_same_on_serial_and_openmp(backend, index):
    a, _, _ = run_gather(backend, index, "uniform", 3)
    b, _, _ = run_gather(backend, index, "uniform", 3)
    np.testing.assert_array_equal(a["neighbors"], b["neighbors"])
    if backend == "cpu":
        c, _, _ = run_gather("serial", index, "uniform", 3)
        np.testing.assert_array_equal(a["neighbors"], c["neighbors"])


def test_allpairs_gather_visits_in_index_order_and_tiled_matches_untiled():
    for dim in (2, 3):
        a, _, _ = run_gather("cpu", "allpairs", "uniform", dim)
        t, _, _ = run_gather("cpu", "allpairs_tiled", "uniform", dim)
        np.testing.assert_array_equal(a["offsets"], t["offsets"])
        np.testing.assert_array_equal(a["neighbors"], t["neighbors"])
        for i in range(0, len(a["offsets"]) - 1, 97):
            seg = a["neighbors"][a["offsets"][i] : a["offsets"][i + 1]]
            assert np.all(np.diff(seg) > 0)


@pytest.mark.parametrize("index", INDEXES)
def test_nonfinite_positions_are_nobodys_neighbours_and_break_nothing(backend, index):
    pos, lo, hi, radius = uniform_box(3, n=500)
    pos[:3] = np.nan
    pos[3] = [np.inf, 0.5, 0.5]
    pos[4] = [0.5, -np.inf, 0.5]
    res = T.gather(backend, index, pos, radius, lo=lo, hi=hi, list_radius=radius * 1.25)
    assert np.all(np.diff(res["offsets"])[:5] == 0)
    assert not np.isin(res["neighbors"], np.arange(5)).any()
    assert_same_neighbours(res, pos, radius, exact=backend != "cuda")


@pytest.mark.parametrize("index", INDEXES)
@pytest.mark.parametrize("dim", [2, 3])
def test_indexes_over_no_particle_and_one_particle(backend, index, dim):
    lo, hi = [0.0] * dim, [1.0] * dim
    empty = T.gather(backend, index, np.zeros((0, dim), np.float32), 0.1, lo=lo, hi=hi, list_radius=0.2)
    assert empty["offsets"].tolist() == [0] and len(empty["neighbors"]) == 0
    assert T.pairs(backend, index, np.zeros((0, dim), np.float32), 0.1, lo=lo, hi=hi, list_radius=0.2).shape == (0, 2)
    one = T.gather(backend, index, np.full((1, dim), 0.5, np.float32), 0.1, lo=lo, hi=hi, list_radius=0.2)
    assert one["offsets"].tolist() == [0, 1] and one["neighbors"].tolist() == [0]  # itself
    assert T.pairs(backend, index, np.full((1, dim), 0.5, np.float32), 0.1, lo=lo, hi=hi, list_radius=0.2).shape == (0, 2)


# --------------------------------------------------------------------------------------
# tags: layers and batched scenes
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("index", GRID_INDEXES)
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("mode", ["all", "own", "range"])
def test_grid_gathers_from_the_chosen_tags_and_skips_unused_slots(backend, index, dim, mode):
    pos, lo, hi, radius = uniform_box(dim, n=1000, seed=11)
    rng = np.random.default_rng(12)
    tags = rng.integers(-1, 3, len(pos)).astype(np.int32)
    kw = dict(tags=tags, ntags=3, tag_mode=mode, tag_range=(1, 3))
    res = T.gather(backend, index, pos, radius, lo=lo, hi=hi, list_radius=radius * 1.25, **kw)
    assert np.all(np.diff(res["offsets"])[tags < 0] == 0)
    assert_same_neighbours(res, pos, radius, exact=backend != "cuda", **kw)
    pairs = T.pairs(backend, index, pos, radius, lo=lo, hi=hi, list_radius=radius * 1.25, **kw)
    if mode != "range":  # a range restricts j only, which makes it one-sided: no pair symmetry
        assert_pairs_once(pairs, pos, radius, exact=backend != "cuda", **kw)


# --------------------------------------------------------------------------------------
# the 4 x 1 x 1 m tank at 1 cm
# --------------------------------------------------------------------------------------
def test_a_4x1x1_metre_domain_at_1cm_cells_finds_the_brute_force_neighbours(backend):
    rng = np.random.default_rng(13)
    centres = np.array([[0.02, 0.02, 0.02], [1.3, 0.5, 0.5], [2.71, 0.99, 0.01], [3.98, 0.5, 0.97]], np.float32)
    pos = np.concatenate([c + rng.uniform(-0.03, 0.03, (500, 3)) for c in centres]).astype(np.float32)
    res = T.gather(backend, "grid", pos, 0.01, lo=[0, 0, 0], hi=[4, 1, 1])
    assert_same_neighbours(res, pos, 0.01, exact=backend != "cuda")
    assert res["offsets"][-1] > 3 * len(pos)  # the clusters are dense: real neighbours, not only self


# --------------------------------------------------------------------------------------
# CSR lists
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("index", ["csr_grid", "csr_allpairs"])
def test_csr_lists_equal_the_gathered_sets_and_cut_the_skin_at_query_time(backend, index):
    pos, lo, hi, radius = uniform_box(3, n=1000, seed=14)
    grid = T.gather(backend, "grid", pos, radius, lo=lo, hi=hi)
    for skin in (1.0, 1.5):
        csr = T.gather(backend, index, pos, radius, lo=lo, hi=hi, list_radius=radius * skin)
        np.testing.assert_array_equal(csr["offsets"], grid["offsets"])
        assert_same_neighbours(csr, pos, radius, exact=backend != "cuda")
        assert csr["capacity"] >= csr["offsets"][-1]


@pytest.mark.parametrize("index", ["csr_grid", "csr_allpairs"])
@pytest.mark.parametrize("dim", [2, 3])
def test_csr_lists_grow_when_particles_crowd_and_keep_their_buffer_after(backend, index, dim):
    rng = np.random.default_rng(15)
    n = 800
    sparse = rng.random((n, dim), dtype=np.float32)
    crowded = (rng.random((n, dim), dtype=np.float32) * np.float32(0.2)).astype(np.float32)
    radius = 0.05
    lists = T.csr_rebuilds(backend, index, [sparse, crowded, sparse, crowded], radius, lo=[0.0] * dim,
                           hi=[1.0] * dim, list_radius=radius)
    totals = [int(l["offsets"][-1]) for l in lists]
    assert totals[1] > 4 * totals[0]  # crowding multiplies the pairs
    assert [l["grows"] for l in lists] == [1, 2, 2, 2]  # grown once for the crowd, never shrunk
    assert lists[2]["capacity"] == lists[1]["capacity"] >= totals[1]
    for l, p in zip(lists, [sparse, crowded, sparse, crowded]):
        assert_same_neighbours(l, p, radius, exact=backend != "cuda")


def test_csr_list_radius_beyond_the_grid_radius_is_refused():
    pos, lo, hi, radius = uniform_box(3, n=50)
    # the CSR kinds build the grid for the list radius; a query radius above it is refused
    with pytest.raises(ValueError, match="exceeds the list radius"):
        T.gather("cpu", "csr_grid", pos, radius * 2, lo=lo, hi=hi, list_radius=radius)


# --------------------------------------------------------------------------------------
# CUDA against the CPU
# --------------------------------------------------------------------------------------
@pytest.mark.gpu
@requires_cuda
@pytest.mark.parametrize("dim", [2, 3])
def test_cuda_grid_sort_matches_the_cpu_bitwise(dim):
    rng = np.random.default_rng(16)
    n = 20000
    pos = rng.uniform(-0.1, 1.1, (n, dim)).astype(np.float32)
    tags = rng.integers(-1, 4, n).astype(np.int32)
    a = T.grid_sort("cuda", pos, 0.02, [0.0] * dim, [1.0] * dim, tags=tags, ntags=4)
    b = T.grid_sort("serial", pos, 0.02, [0.0] * dim, [1.0] * dim, tags=tags, ntags=4)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.gpu
@requires_cuda
@pytest.mark.parametrize("index", INDEXES)
def test_cuda_gather_visits_the_cpu_neighbours_in_the_cpu_order(index):
    # same keys, same stable sort, same walk: the lists agree entry for entry except for
    # pairs at the radius that FMA rounding moves
    a, pos, radius = run_gather("cuda", index, "elongated", 3)
    b, _, _ = run_gather("serial", index, "elongated", 3)
    if np.array_equal(a["offsets"], b["offsets"]):
        np.testing.assert_array_equal(a["neighbors"], b["neighbors"])
    assert_same_neighbours(a, pos, radius, exact=False)


@pytest.mark.gpu
@requires_cuda
def test_cuda_backend_on_a_named_device_and_a_missing_one():
    pos, lo, hi, radius = uniform_box(3, n=300)
    res = T.gather("cuda:0", "grid", pos, radius, lo=lo, hi=hi)
    assert_same_neighbours(res, pos, radius, exact=False)
    with pytest.raises(ValueError, match="does not exist"):
        T.gather("cuda:999", "grid", pos, radius, lo=lo, hi=hi)


# --------------------------------------------------------------------------------------
# the cell walk leaves out the cells wholly beyond the query radius
# --------------------------------------------------------------------------------------
def walked_reference(pos, cell_radius, query_radius, lo, hi):
    """The candidates a cell walk reads when it leaves out every cell of the 3^D block whose box
    lies farther than the query radius from the particle (float64; the C++ margin of 1e-5 on r^2),
    and the candidates of the whole block."""
    pos = np.asarray(pos, np.float64)
    d = pos.shape[1]
    spec = T.cell_grid_spec(d, lo, hi, cell_radius)
    cell, dims, origin = spec["cell"], np.asarray(spec["dims"]), np.asarray(lo, np.float64)
    c = np.clip(np.floor((pos - origin) / cell).astype(np.int64), 0, dims - 1)
    counts = {}
    for cc in map(tuple, c):
        counts[cc] = counts.get(cc, 0) + 1
    lim = np.float32(query_radius) ** 2 * (1 + 1e-5)
    near, block = np.zeros(len(pos), np.int64), np.zeros(len(pos), np.int64)
    for i, (x, ci) in enumerate(zip(pos, c)):
        face = origin + ci * cell
        for off in np.ndindex(*(3,) * d):
            o = np.asarray(off) - 1
            cj = ci + o
            if np.any(cj < 0) or np.any(cj >= dims):
                continue
            k = counts.get(tuple(cj), 0)
            gap = np.where(o < 0, x - face, np.where(o > 0, face + cell - x, 0.0))
            block[i] += k
            if np.sum(np.maximum(gap, 0.0) ** 2) <= lim:
                near[i] += k
    return near, block


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("query", [1.0, 0.8])
def test_cell_walk_reads_only_the_cells_within_reach(backend, dim, query):
    # a uniform gas in cells of the radius: the 3-D walk reads about 20.6 of the 27 cells
    # (1 + 6 + 12 pi/4 + 8 pi/6), 2-D 8.1 of 9 (1 + 4 + 4 pi/4); and every neighbour is still
    # found (the gather tests above); positions beyond the domain clamp into border cells
    rng = np.random.default_rng(7 + dim)
    r = 0.1
    lo, hi = [0.0] * dim, [1.0] * dim
    pos = rng.uniform(-0.05, 1.05, (3000 if dim == 3 else 1500, dim)).astype(np.float32)
    got = T.grid_walked(backend, pos, r, lo, hi, query_radius=r * query)
    near, block = walked_reference(pos, r, r * query, lo, hi)
    np.testing.assert_array_equal(got, near)
    # in rows: the same cells (each row's kept cells as one range)
    np.testing.assert_array_equal(T.grid_walked(backend, pos, r, lo, hi, query_radius=r * query, order="rows"), near)
    want, _ = brute_codes(pos, r * query)
    assert np.all(got >= np.bincount(want // len(pos), minlength=len(pos)))  # (every neighbour's cell is read)
    share = got.sum() / block.sum()
    if query == 1.0:
        assert share == pytest.approx((1 + 6 + 3 * np.pi + 4 * np.pi / 3) / 27 if dim == 3 else (5 + np.pi) / 9, abs=0.04)
    assert share < (0.82 if dim == 3 else 0.95)
