"""The engine's exec primitives (cpp/src/cpu/exec_cpu.h, cpp/src/cuda/exec_cuda.cuh) through
corpuscle._testing, against NumPy references on random inputs: exclusive scan (int32 and
uint32 into the same type or int64), stream compaction, segmented reduce, the 64-bit key
sort, tiles with shared memory and syncs, flag-guarded loops and atomics. Serial and OpenMP
must agree bitwise; CUDA (``gpu`` mark, skipped cleanly without a device) must match NumPy
and the CPU.
"""

import numpy as np
import pytest

from corpuscle import _testing as T

CUDA, CUDA_WHY = T.cuda_available()
requires_cuda = pytest.mark.skipif(not CUDA, reason=f"no usable CUDA backend: {CUDA_WHY}")

# empty, one, around one CUDA block (128 threads) and one CUB tile, and well beyond
SIZES = [0, 1, 2, 127, 128, 129, 1025, 70001]


def exclusive_ref(x, dtype):
    out = np.zeros(len(x), dtype=dtype)
    if len(x):
        out[1:] = np.cumsum(x.astype(dtype), dtype=dtype)[:-1]
    return out, (np.sum(x.astype(dtype), dtype=dtype) if len(x) else dtype(0))


# --------------------------------------------------------------------------------------
# exclusive scan
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("dtype", [np.int32, np.uint32])
@pytest.mark.parametrize("wide", [False, True], ids=["same_type", "into_int64"])
def test_exclusive_scan_matches_numpy_with_its_total(backend, n, dtype, wide):
    rng = np.random.default_rng(n * 4 + wide * 2 + (dtype is np.uint32))
    if wide:
        x = rng.integers(0, 2**20 if dtype is np.int32 else 2**31, n).astype(dtype)  # totals beyond 2^31
    elif dtype is np.int32:
        x = rng.integers(-1000, 1000, n).astype(dtype)
    else:
        x = rng.integers(0, 2**32, n, dtype=np.uint64).astype(dtype)  # wraps modulo 2^32, like NumPy
    out, total = T.exclusive_scan(backend, x, wide)
    ref_type = np.int64 if wide else dtype
    ref, ref_total = exclusive_ref(x, ref_type)
    assert out.dtype == ref_type
    np.testing.assert_array_equal(out, ref)
    assert total == ref_total


def test_exclusive_scan_serial_equals_openmp_bitwise():
    x = np.random.default_rng(1).integers(0, 2**31, 200001).astype(np.uint32)
    a, ta = T.exclusive_scan("serial", x, True)
    b, tb = T.exclusive_scan("cpu", x, True)
    assert a.tobytes() == b.tobytes() and ta == tb
    assert ta > 2**40  # really needed 64 bits


# --------------------------------------------------------------------------------------
# stream compaction
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("density", [0.0, 0.03, 0.5, 1.0])
def test_select_flagged_keeps_the_flagged_indices_in_order(backend, n, density):
    rng = np.random.default_rng(n + int(density * 100))
    flags = (rng.random(n) < density).astype(np.int32) * rng.integers(1, 5, n).astype(np.int32)  # any nonzero flags
    got = T.select_flagged(backend, flags)
    np.testing.assert_array_equal(got, np.flatnonzero(flags))


# --------------------------------------------------------------------------------------
# segmented reduce
# --------------------------------------------------------------------------------------
def random_segments(rng, n, nseg):
    cuts = np.sort(rng.integers(0, n + 1, max(nseg - 1, 0)))
    return np.concatenate([[0], cuts, [n]]).astype(np.int64) if nseg > 0 else np.zeros(1, np.int64)


def sequential_float_sum(x, init):
    """Left to right in float32, as the CPU backends sum a segment."""
    acc = np.float32(init)
    if len(x):
        acc = np.cumsum(np.concatenate([[np.float32(init)], x]).astype(np.float32), dtype=np.float32)[-1]
    return acc


@pytest.mark.parametrize("n,nseg", [(0, 0), (0, 3), (1, 1), (129, 7), (5000, 1), (20000, 333), (3000, 3000)])
@pytest.mark.parametrize("op", ["sum", "min", "max"])
def test_segmented_reduce_float_matches_numpy(backend, n, nseg, op):
    rng = np.random.default_rng(n + nseg)
    items = rng.normal(size=n).astype(np.float32)
    off = random_segments(rng, n, nseg)
    init = {"sum": 0.0, "min": np.inf, "max": -np.inf}[op]
    got = T.segmented_reduce(backend, items, off.astype(np.int32), op, init)
    assert got.shape == (len(off) - 1,)
    for s in range(len(off) - 1):
        seg = items[off[s] : off[s + 1]]
        if op == "sum":
            if backend == "cuda":  # a tree, not left to right: rounding only
                np.testing.assert_allclose(got[s], np.sum(seg, dtype=np.float64), rtol=1e-4, atol=1e-3)
            else:
                assert got[s] == sequential_float_sum(seg, init)
        else:
            ref = np.float32(init) if len(seg) == 0 else (seg.min() if op == "min" else seg.max())
            assert got[s] == ref


@pytest.mark.parametrize("op", ["sum", "min", "max"])
def test_segmented_reduce_int_with_int64_offsets_matches_numpy(backend, op):
    rng = np.random.default_rng(3)
    n = 50000
    items = rng.integers(-10**4, 10**4, n).astype(np.int32)
    off = random_segments(rng, n, 1000)
    init = {"sum": 7, "min": 2**31 - 1, "max": -(2**31)}[op]
    got = T.segmented_reduce(backend, items, off, op, init)
    f = {"sum": lambda s: init + int(s.sum()), "min": lambda s: min(init, int(s.min(initial=init))),
         "max": lambda s: max(init, int(s.max(initial=init)))}[op]
    np.testing.assert_array_equal(got, [f(items[off[s] : off[s + 1]]) for s in range(len(off) - 1)])


def test_segmented_reduce_serial_equals_openmp_bitwise():
    rng = np.random.default_rng(4)
    items = rng.normal(size=100000).astype(np.float32)
    off = random_segments(rng, len(items), 257).astype(np.int32)
    a = T.segmented_reduce("serial", items, off, "sum", 0.0)
    b = T.segmented_reduce("cpu", items, off, "sum", 0.0)
    assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("n", [0, 1, 1000, 300001])
@pytest.mark.parametrize("op", ["sum", "max"])
def test_fused_reduce_equals_the_reduction_of_stored_items_and_runs_its_follow_up(backend, n, op):
    # for_each_reduce_then: the items come from the stage function and are never stored
    rng = np.random.default_rng(n + 17)
    items = rng.normal(size=n).astype(np.float32)
    init = {"sum": 0.0, "max": -np.inf}[op]  # op's identity (every thread and chunk starts from it)
    fused, twice, stored = T.fused_reduce(backend, items, op, init)
    assert twice == np.float32(2.0) * fused  # the follow-up read the result
    if op == "max":
        assert fused == (np.float32(init) if n == 0 else max(np.float32(init), items.max()))
    elif backend == "cuda":  # blocks' trees, not left to right: rounding only; the same every run
        np.testing.assert_allclose(fused, init + np.sum(items, dtype=np.float64), rtol=1e-5, atol=1e-3)
        again = T.fused_reduce(backend, items, op, init)
        assert again.tobytes() == np.array([fused, twice, stored], np.float32).tobytes()
    else:  # the CPU's chunks and order: bit for bit the reduction of the stored items
        assert np.float32(fused).tobytes() == np.float32(stored).tobytes()
        np.testing.assert_allclose(fused, init + np.sum(items, dtype=np.float64), rtol=1e-5, atol=1e-3)


# --------------------------------------------------------------------------------------
# 64-bit key sort
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("bits", [64, 40, 7])
def test_sort_pairs64_is_stable_and_matches_numpy(backend, n, bits):
    rng = np.random.default_rng(n + bits)
    mask = np.uint64(2**64 - 1) if bits == 64 else np.uint64(2**bits - 1)
    keys = rng.integers(0, 2**64 - 1, n, dtype=np.uint64, endpoint=True) & mask
    if n > 10:
        keys[: n // 3] = keys[n // 3 : 2 * (n // 3)]  # many equal keys: stability shows
        keys[-1] = mask  # the all-ones key (a grid's sentinel) sorts last
    vals = np.arange(n, dtype=np.int32)
    ko, vo = T.sort_pairs64(backend, keys, vals, bits)
    order = np.argsort(keys, kind="stable")
    np.testing.assert_array_equal(ko, keys[order])
    np.testing.assert_array_equal(vo, vals[order])


def test_sort_pairs64_looks_at_the_low_bits_only(backend):
    rng = np.random.default_rng(5)
    low = rng.integers(0, 2**12, 1000).astype(np.uint64)
    keys = low | (rng.integers(0, 2**20, 1000).astype(np.uint64) << np.uint64(40))  # junk above bit 12
    ko, vo = T.sort_pairs64(backend, keys, np.arange(1000, dtype=np.int32), 12)
    order = np.argsort(low, kind="stable")
    np.testing.assert_array_equal(vo, order)
    np.testing.assert_array_equal(ko, keys[order])


def test_sort_pairs64_serial_equals_openmp_bitwise_on_the_parallel_path():
    rng = np.random.default_rng(6)
    keys = rng.integers(0, 5000, 120000).astype(np.uint64) << np.uint64(30)  # > 50,000: parallel sort
    vals = rng.integers(-(2**31), 2**31 - 1, 120000).astype(np.int32)
    a = T.sort_pairs64("serial", keys, vals, 64)
    b = T.sort_pairs64("cpu", keys, vals, 64)
    assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()


# --------------------------------------------------------------------------------------
# tiles
# --------------------------------------------------------------------------------------
def tile_reference(x, K):
    n = len(x)
    nt = (n + K - 1) // K
    pad = np.zeros(nt * K, np.float32)
    pad[:n] = x
    out = np.zeros(nt * K, np.float32)
    lanes = np.arange(K)
    for t in range(nt):
        sh = pad[t * K : (t + 1) * K]
        total = np.float32(sh.astype(np.int64).sum())
        out[t * K : (t + 1) * K] = (sh[(lanes + 1) % K] + sh[K - 1 - lanes] + np.float32(2) * sh) + total
    return out[:n]


@pytest.mark.parametrize("tile", [32, 128])
@pytest.mark.parametrize("n", [0, 1, 31, 32, 33, 129, 1000, 4097])
def test_tile_lanes_share_memory_across_syncs(backend, tile, n):
    x = np.random.default_rng(n + tile).integers(-100, 100, n).astype(np.float32)
    np.testing.assert_array_equal(T.tile_exercise(backend, x, tile), tile_reference(x, tile))


# --------------------------------------------------------------------------------------
# flag-guarded loops
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [0, 1, 129, 300000])
def test_for_each_if_runs_only_when_the_flag_is_set(backend, n):
    np.testing.assert_array_equal(T.for_each_if(backend, 0, n), np.zeros(n, np.int32))
    np.testing.assert_array_equal(T.for_each_if(backend, 1, n), np.arange(1, n + 1, dtype=np.int32))
    np.testing.assert_array_equal(T.for_each_if(backend, -7, n), np.arange(1, n + 1, dtype=np.int32))


# --------------------------------------------------------------------------------------
# atomics
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 129, 100000])
def test_atomics_add_max_min_and_cas_under_contention(backend, n):
    v = np.random.default_rng(n).integers(-100, 100, n).astype(np.int32)
    r = T.atomics(backend, v)
    assert r["isum"] == int(v.sum())
    assert r["imax"] == int(v.max()) and r["imin"] == int(v.min())
    assert r["wins"] == 1 and 0 <= r["owner"] < n  # exactly one compare-and-swap won
    assert r["usum"] == int((v & 0xFF).astype(np.int64).sum()) % 2**32
    assert r["fsum"] == float(v.sum())  # small integers: exact in any order


# --------------------------------------------------------------------------------------
# CUDA against the CPU
# --------------------------------------------------------------------------------------
@pytest.mark.gpu
@requires_cuda
def test_cuda_primitives_match_the_cpu():
    rng = np.random.default_rng(7)
    n = 300001
    x = rng.integers(0, 2**20, n).astype(np.int32)
    a, ta = T.exclusive_scan("cuda", x, True)
    b, tb = T.exclusive_scan("serial", x, True)
    assert a.tobytes() == b.tobytes() and ta == tb
    flags = (rng.random(n) < 0.3).astype(np.int32)
    assert T.select_flagged("cuda", flags).tobytes() == T.select_flagged("serial", flags).tobytes()
    keys = rng.integers(0, 2**40, n).astype(np.uint64)
    vals = np.arange(n, dtype=np.int32)
    ka, va = T.sort_pairs64("cuda", keys, vals, 40)
    kb, vb = T.sort_pairs64("serial", keys, vals, 40)
    assert ka.tobytes() == kb.tobytes() and va.tobytes() == vb.tobytes()
    items = rng.normal(size=n).astype(np.float32)
    off = random_segments(rng, n, 999).astype(np.int32)
    for op in ("min", "max"):
        init = np.inf if op == "min" else -np.inf
        assert (T.segmented_reduce("cuda", items, off, op, init).tobytes()
                == T.segmented_reduce("serial", items, off, op, init).tobytes())
    np.testing.assert_allclose(T.segmented_reduce("cuda", items, off, "sum", 0.0),
                               T.segmented_reduce("serial", items, off, "sum", 0.0), rtol=1e-4, atol=1e-3)
    # CUB's segmented reduce repeats itself bitwise
    assert (T.segmented_reduce("cuda", items, off, "sum", 0.0).tobytes()
            == T.segmented_reduce("cuda", items, off, "sum", 0.0).tobytes())
    t = rng.integers(-100, 100, 10000).astype(np.float32)
    for tile in (32, 128):
        assert T.tile_exercise("cuda", t, tile).tobytes() == T.tile_exercise("serial", t, tile).tobytes()


# ---- lane widths: a stage's own number of cooperating lanes per item -------------------

@pytest.mark.parametrize("width", [1, 2, 4, 8, 16, 32])
def test_lanes_of_every_width_find_the_brute_force_neighbours(backend, width):
    # 300 points (not a multiple of any width, so groups of a warp end at different items)
    # and a radius that gives each a different number of neighbours
    rng = np.random.default_rng(width)
    pos = rng.uniform(0.0, 1.0, size=(300, 3)).astype(np.float32)
    radius = 0.2
    counts, sums = T.lanes_gather(backend, pos.reshape(-1), radius, width)
    d = pos[:, None, :].astype(np.float64) - pos[None, :, :]
    r2 = (d * d).sum(axis=2)
    inside = r2 < radius * radius
    np.testing.assert_array_equal(counts, inside.sum(axis=1))
    np.testing.assert_allclose(sums, np.where(inside, r2, 0.0).sum(axis=1), rtol=1e-5, atol=1e-7)


def test_a_lane_width_that_is_not_a_power_of_two_is_refused():
    with pytest.raises(ValueError, match="lane width must be 1, 2, 4, 8, 16 or 32, got 3"):
        T.lanes_gather("serial", np.zeros(6, dtype=np.float32), 0.1, 3)
