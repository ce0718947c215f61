"""spatial/lbvh.h's walk on a hierarchy whose traversal needs exactly as many stack entries as
the stack has: a comb (each node on the leftmost path has an internal right child, which the
walk pushes while it goes down left), built here so that a query covering it all pushes S
entries. With a stack of S entries every query visits exactly the slots a brute-force search
finds and nothing overflows; with S - 1 the overflow flag is raised. Run at the default depth
(kLbvhStack) and at the most the CPU's local array holds (kLbvhMaxStack), where asking for
more is clamped (a tree needing one more entry overflows). A stack one entry short anywhere
in the walk (the capacity test, the clamp) fails here."""

from __future__ import annotations

import numpy as np
import pytest

_testing = pytest.importorskip("corpuscle._testing")


def comb(S: int):
    """A hierarchy of n = 2 S + 2 leaves whose walk pushes S right children on the way down.

    Internal nodes: the root A_0 = 0, the leftmost path A_k = k (k = 1..S), the pushed right
    children B_k = S + k (k = 1..S); A_{k-1} = (A_k, B_k); A_S and every B_k hold two leaves.
    Slots in walk order: A_S's 0, 1; then B_S's, B_{S-1}'s, ..., B_1's. Leaves on the x axis
    at their slot; boxes are the leaves' bounding boxes."""
    n = 2 * S + 2
    left = np.zeros(n - 1, np.int32)
    right = np.zeros(n - 1, np.int32)
    slots: dict[int, list[int]] = {}

    def leaf(j):
        return (n - 1) + j

    def b(k):
        return S + k

    left[S], right[S] = leaf(0), leaf(1)
    slots[S] = [0, 1]
    for k in range(S, 0, -1):
        j = 2 * (S - k) + 2
        left[b(k)], right[b(k)] = leaf(j), leaf(j + 1)
        slots[b(k)] = [j, j + 1]
    for k in range(S, 0, -1):  # A_{k-1} = (A_k, B_k)
        left[k - 1], right[k - 1] = k, b(k)
        slots[k - 1] = slots[k] + slots[b(k)]
    pos = np.zeros((n, 2), np.float32)
    pos[:, 0] = np.arange(n, dtype=np.float32)
    pos[:, 1] = 0.25 * (np.arange(n) % 3)
    boxes = np.zeros((n - 1, 4), np.float32)
    rightmost = np.zeros(n - 1, np.int32)
    for c in range(n - 1):
        p = pos[slots[c]]
        boxes[c, :2], boxes[c, 2:] = p.min(axis=0), p.max(axis=0)
        rightmost[c] = max(slots[c])
    return pos, left, right, rightmost, boxes


def needed_stack(left, right, n):
    """The most entries the walk keeps when every box overlaps (depth-first, left first,
    pushing the right child when both children are internal): float-free reference."""
    best, stack, node = 0, [], 0
    while True:
        kids = [left[node], right[node]]
        inner = [k < n - 1 for k in kids]
        if inner[0]:
            if inner[1]:
                stack.append(kids[1])
                best = max(best, len(stack))
            node = kids[0]
        elif inner[1]:
            node = kids[1]
        else:
            if not stack:
                return best
            node = stack.pop()


def walk(tree, qlo, qhi, depth, after=False):
    pos, left, right, rightmost, boxes = tree
    return _testing.lbvh_walk(pos, left, right, rightmost, boxes, np.ascontiguousarray(qlo, np.float32),
                              np.ascontiguousarray(qhi, np.float32), depth, after)


def brute(pos, qlo, qhi, after=False):
    out = []
    for q in range(len(qlo)):
        inside = np.all((pos >= qlo[q]) & (pos <= qhi[q]), axis=1)
        if after:
            inside &= np.arange(len(pos)) > q
        out.append(set(np.flatnonzero(inside).tolist()))
    return out


DEFAULT, MAXIMUM = _testing.lbvh_stack_sizes()


@pytest.mark.parametrize("S", [DEFAULT, MAXIMUM])
@pytest.mark.parametrize("after", [False, True])
def test_a_tree_as_deep_as_the_stack(S, after):
    tree = comb(S)
    pos, left, right = tree[0], tree[1], tree[2]
    n = len(pos)
    assert needed_stack(left, right, n) == S
    # every slot's query box covers the whole tree (the walk needs all S entries), plus
    # boxes around each slot (walks that need fewer) and one that holds nothing
    big = np.array([[-1.0, -1.0]] * 2)
    qlo = np.concatenate([np.repeat(big[:1], 2, axis=0), pos - 1.5, [[-10.0, 5.0]]])
    qhi = np.concatenate([np.repeat([[n + 1.0, 1.0]], 2, axis=0), pos + 1.5, [[-9.0, 6.0]]])
    seen, overflow = walk(tree, qlo, qhi, S, after)
    assert overflow == 0
    ref = brute(pos, qlo, qhi, after)
    for q, (s, r) in enumerate(zip(seen, ref)):
        assert len(s) == len(set(s.tolist())) and set(s.tolist()) == r, q
    # one entry short: the full query overflows (the flag, never a write past the stack)
    _, overflow = walk(tree, qlo[:2], qhi[:2], S - 1, after)
    assert overflow == 7


def test_the_cpu_stack_holds_at_most_the_maximum():
    tree = comb(MAXIMUM + 1)
    n = len(tree[0])
    qlo, qhi = np.array([[-1.0, -1.0]]), np.array([[n + 1.0, 1.0]])
    seen, overflow = walk(tree, qlo, qhi, MAXIMUM + 1)  # clamped to the local array
    assert overflow == 7
    seen, overflow = walk(comb(MAXIMUM), qlo, qhi, MAXIMUM + 50)
    assert overflow == 0 and len(seen[0]) == 2 * MAXIMUM + 2
