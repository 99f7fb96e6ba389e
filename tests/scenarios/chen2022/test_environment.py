"""mcjax.scenarios.chen2022.environment (Chen & Hao 2022 urban geometry) against independent references:
shapely footprint intersection plus a numpy (or exact fractions.Fraction) height check for
line of sight, scipy.spatial.ConvexHull for the eqs. 7–8 shadow polyhedra,
scipy.optimize.minimize of the reflected path length for the NLOS paths, and math.atan2 for
the bearing."""

import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from scipy.optimize import minimize
from scipy.spatial import ConvexHull

from mcjax.scenarios.chen2022.environment import (
    Buildings,
    check_buildings,
    in_shadow,
    inside,
    line_of_sight,
    measured_bearing,
    mirror_images,
    reflections,
)

# Jitted entry points (one compilation per input shape). Per-case layouts are vmapped
# over the leading axis of the Buildings fields; one common layout is broadcast (in_axes None).
_PER_CASE = Buildings(0, 0, 0)
_los_cases = jax.jit(jax.vmap(line_of_sight, in_axes=(_PER_CASE, 0, 0)))
_shadow_cases = jax.jit(jax.vmap(in_shadow, in_axes=(_PER_CASE, 0, 0)))
_shadow_one_layout = jax.jit(jax.vmap(in_shadow, in_axes=(None, None, 0)))
_refl_cases = jax.jit(jax.vmap(reflections, in_axes=(_PER_CASE, 0, 0)))
_bearing_one_layout = jax.jit(jax.vmap(measured_bearing, in_axes=(None, None, 0, None)))
_los_one_layout = jax.jit(jax.vmap(line_of_sight, in_axes=(None, None, 0)))
_refl_one_layout = jax.jit(jax.vmap(reflections, in_axes=(None, None, 0)))
# unbatched entry points (eager dispatch would compile every primitive separately)
_los = jax.jit(line_of_sight)
_shadow = jax.jit(in_shadow)
_inside = jax.jit(inside)
_refl = jax.jit(reflections, static_argnames="check_legs")
_bearing = jax.jit(measured_bearing, static_argnames="check_legs")


def _no_buildings():
    return check_buildings(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))


# --------------------------------------------------------------------------- reference


def _reference_blocked(a, b, lo, hi, h):
    """Independent segment-vs-box test, elementwise over cases (N,).

    Footprint: shapely (closed sets) on the ground projection of the segment. Height: clip
    the segment parameter to the footprint's slab interval and check that z(t), linear on
    that interval, reaches [0, h]. Works on float arrays and on object arrays of Fractions
    (exact)."""
    fa = np.asarray(a[:, :2], float)
    fb = np.asarray(b[:, :2], float)
    degenerate = np.all(fa == fb, axis=1)
    geoms = np.where(degenerate, shapely.points(fa), shapely.linestrings(np.stack([fa, fb], 1)))
    boxes = shapely.box(*np.asarray(lo, float).T, *np.asarray(hi, float).T)
    footprint = shapely.intersects(geoms, boxes)
    d = b - a
    t0 = np.zeros(len(a), dtype=a.dtype) if a.dtype != object else np.full(len(a), Fraction(0))
    t1 = t0 + 1
    for k in range(2):
        dk = d[:, k]
        zero = dk == 0
        safe = np.where(zero, 1, dk)
        ta = (lo[:, k] - a[:, k]) / safe
        tb = (hi[:, k] - a[:, k]) / safe
        t0 = np.where(zero, t0, np.maximum(t0, np.minimum(ta, tb)))
        t1 = np.where(zero, t1, np.minimum(t1, np.maximum(ta, tb)))
    # the 2-D clip must agree with shapely (two references checking each other)
    in_slabs = np.all((a[:, :2] >= lo) & (a[:, :2] <= hi) | (d[:, :2] != 0), axis=1)
    np.testing.assert_array_equal(footprint, (t0 <= t1) & in_slabs)
    z0 = a[:, 2] + t0 * d[:, 2]
    z1 = a[:, 2] + t1 * d[:, 2]
    return footprint & (np.minimum(z0, z1) <= h) & (np.maximum(z0, z1) >= 0)


def _random_cases(rng, n):
    lo = rng.uniform(0, 10, (n, 2))
    hi = lo + rng.uniform(2, 8, (n, 2))
    h = rng.uniform(2, 12, n)
    a = np.concatenate([rng.uniform(-2, 16, (n, 2)), rng.uniform(0, 12, (n, 1))], 1)
    b = np.concatenate([rng.uniform(-2, 16, (n, 2)), rng.uniform(0, 12, (n, 1))], 1)
    return lo, hi, h, a, b


# --------------------------------------------------------------------------- line of sight


def test_line_of_sight_random_vs_shapely():
    rng = np.random.default_rng(3)
    n = 12000
    lo, hi, h, a, b = _random_cases(rng, n)
    ref = _reference_blocked(a, b, lo, hi, h)
    bld = Buildings(jnp.asarray(lo[:, None]), jnp.asarray(hi[:, None]), jnp.asarray(h[:, None]))
    los = np.asarray(_los_cases(bld, a, b))
    shadow = np.asarray(_shadow_cases(bld, a, b))
    assert 0.15 < ref.mean() < 0.85  # a real mix of blocked and clear segments
    np.testing.assert_array_equal(~los, ref)
    np.testing.assert_array_equal(shadow, ref)
    # symmetric in the end points
    np.testing.assert_array_equal(np.asarray(_los_cases(bld, b, a)), los)


def _exact_blocked_any(a, b, lo, hi, h):
    """Exact (Fractions) "the segment a–b meets one of the boxes": ``lo``, ``hi`` (N, B, 2),
    ``h`` (N, B) integers, ``a``, ``b`` (N, 3) integers or Fractions; per box
    :func:`_reference_blocked`, OR-ed. Returns (N,) bool."""
    frac = np.vectorize(Fraction, otypes=[object])
    fa, fb = (x if x.dtype == object else frac(x) for x in (a, b))
    out = np.zeros(len(a), bool)
    for j in range(lo.shape[1]):
        out |= _reference_blocked(fa, fb, frac(lo[:, j]), frac(hi[:, j]), frac(h[:, j])).astype(bool)
    return out


def _as_buildings(lo, hi, h):
    return Buildings(jnp.asarray(lo, float), jnp.asarray(hi, float), jnp.asarray(h, float))


def test_line_of_sight_integer_grid_exact():
    """Integer coordinates, two and three boxes per case: touching faces, edges, corners and
    roofs are common; the reference is exact (Fractions) and the closed convention says
    touching blocks. Coordinates up to 40 make most slab quotients inexact (1/3, 1/7, ...),
    so a division rewritten as a multiplication by the reciprocal would show."""
    rng = np.random.default_rng(5)
    n = 3000
    for nb, span in ((2, 3), (3, 40)):
        lo = rng.integers(0, span, (n, nb, 2))
        hi = lo + rng.integers(1, max(3, span), (n, nb, 2))
        h = rng.integers(1, max(4, span), (n, nb))
        a = np.concatenate([rng.integers(-1, 2 * span, (n, 2)), rng.integers(0, span, (n, 1))], 1)
        b = np.concatenate([rng.integers(-1, 2 * span, (n, 2)), rng.integers(0, span, (n, 1))], 1)
        ref = _exact_blocked_any(a, b, lo, hi, h)
        los = np.asarray(_los_cases(_as_buildings(lo, hi, h), a.astype(float), b.astype(float)))
        np.testing.assert_array_equal(~los, ref)
        assert 0.1 < ref.mean() < 0.9
    # the small grid really exercises the boundary (the last layout of span 3 is gone; redo one)
    lo = rng.integers(0, 3, (n, 2))
    hi = lo + rng.integers(1, 3, (n, 2))
    a = np.concatenate([rng.integers(-1, 6, (n, 2)), rng.integers(0, 5, (n, 1))], 1).astype(float)
    b = np.concatenate([rng.integers(-1, 6, (n, 2)), rng.integers(0, 5, (n, 1))], 1).astype(float)
    nondeg = ~np.all(a[:, :2] == b[:, :2], 1)
    touches = shapely.touches(shapely.linestrings(np.stack([a[:, :2], b[:, :2]], 1)[nondeg]),
                              shapely.box(*lo[nondeg].T, *hi[nondeg].T))
    assert touches.sum() > 100


def _touch_cases(rng, n, kind):
    """Segments through a boundary feature of box 0 (its lower corner sits at ``base``), with two
    more boxes in the scene: ``a`` random, the feature ``f`` at a fraction 1/k of the way
    (``b = a + k (f − a)``, k = 1: the end point ON the feature, e.g. a UAV on a roof edge)."""
    base = rng.integers(0, 60, (n, 2))
    size = rng.integers(3, 50, (n, 2))
    h0 = rng.integers(3, 90, n)
    lo0, hi0 = base, base + size
    pick = rng.integers(0, 2, (n, 2)).astype(bool)
    corner_xy = np.where(pick, hi0, lo0)
    along = lo0 + rng.integers(1, 1000, (n, 2)) * size // 1000           # an integer inside the span
    if kind == "roof corner":
        f = np.c_[corner_xy, h0]
    elif kind == "roof edge":                                             # x = x_lo or x_hi, y inside
        f = np.c_[corner_xy[:, 0], along[:, 1], h0]
    elif kind == "vertical edge":
        f = np.c_[corner_xy, rng.integers(0, 90, n) % (h0 + 1)]
    else:                                                                 # "roof": sliding on it
        f = np.c_[along, h0]
    a = np.c_[rng.integers(-200, 200, (n, 2)), rng.integers(0, 150, n)]
    if kind == "roof":
        a[:, 2] = h0
    k = rng.integers(1, 8, n)[:, None]
    b = a + k * (f - a)
    others_lo = rng.integers(-100, 200, (n, 2, 2))
    others_hi = others_lo + rng.integers(1, 60, (n, 2, 2))
    lo = np.concatenate([lo0[:, None], others_lo], 1)
    hi = np.concatenate([hi0[:, None], others_hi], 1)
    h = np.c_[h0, rng.integers(1, 120, (n, 2))]
    keep = ~np.all(a == b, 1)
    return lo[keep], hi[keep], h[keep], a[keep], b[keep]


@pytest.mark.parametrize("kind", ["roof corner", "roof edge", "vertical edge", "roof"])
def test_line_of_sight_touching_with_three_boxes_exact(kind):
    """Segments through a roof corner, along a roof edge or a vertical edge, or sliding on a
    roof, with two more boxes per case: the exact (Fractions) reference against the slab test,
    in both directions. Many cases only touch box 0 (blocked by it, clear of it shrunk by
    1/1000): those are the cases a rounding error would call clear."""
    rng = np.random.default_rng(["roof corner", "roof edge", "vertical edge", "roof"].index(kind))
    lo, hi, h, a, b = _touch_cases(rng, 3000, kind)
    ref = _exact_blocked_any(a, b, lo, hi, h)
    bld = _as_buildings(lo, hi, h)
    np.testing.assert_array_equal(~np.asarray(_los_cases(bld, a.astype(float), b.astype(float))), ref)
    np.testing.assert_array_equal(~np.asarray(_los_cases(bld, b.astype(float), a.astype(float))), ref)
    eps = Fraction(1, 1000)
    frac = np.vectorize(Fraction, otypes=[object])
    touch_only = _reference_blocked(frac(a), frac(b), frac(lo[:, 0]), frac(hi[:, 0]), frac(h[:, 0])).astype(bool)
    touch_only &= ~_reference_blocked(frac(a), frac(b), frac(lo[:, 0]) + eps, frac(hi[:, 0]) - eps,
                                      frac(h[:, 0]) - eps).astype(bool)
    assert touch_only.sum() > 150


def test_reflection_leg_ending_on_a_box_corner_is_blocked():
    """Wall x = x_hi of box 0 reflects towards a UAV that sits exactly on a corner (or a roof
    edge) of box 1, a third box elsewhere: the leg point → UAV ends on box 1, so the
    reflection is blocked (closed convention). Checked against the region test alone
    (``check_legs=False``): in the region, and blocked only by the leg."""
    rng = np.random.default_rng(17)
    n = 3000
    y0 = rng.integers(0, 50, n)
    lo0 = np.c_[np.zeros(n, int), y0]
    hi0 = np.c_[rng.integers(5, 30, n), y0 + rng.integers(40, 120, n)]
    h0 = rng.integers(40, 150, n)
    emitter = np.c_[hi0[:, 0] + rng.integers(1, 60, n), rng.integers(0, 200, n), np.zeros(n, int)]
    uav = np.c_[hi0[:, 0] + rng.integers(1, 200, n), rng.integers(-50, 250, n), rng.integers(1, 120, n)]
    # box 1 has the UAV on its top corner or on a roof edge, and extends away from wall 0
    w1 = rng.integers(1, 30, (n, 2))
    sx = rng.integers(0, 2, n).astype(bool)
    lo1 = np.c_[uav[:, 0], np.where(sx, uav[:, 1], uav[:, 1] - w1[:, 1])]
    hi1 = np.c_[uav[:, 0] + w1[:, 0], np.where(sx, uav[:, 1] + w1[:, 1], uav[:, 1])]
    edge = rng.integers(0, 2, n).astype(bool)                            # roof edge: y strictly inside
    lo1[:, 1] = np.where(edge, uav[:, 1] - w1[:, 1], lo1[:, 1])
    hi1[:, 1] = np.where(edge, uav[:, 1] + w1[:, 1], hi1[:, 1])
    h1 = uav[:, 2]
    lo2 = np.c_[rng.integers(-300, -200, n), rng.integers(-300, -200, n)]
    lo = np.stack([lo0, lo1, lo2], 1)
    hi = np.stack([hi0, hi1, lo2 + 10], 1)
    h = np.c_[h0, h1, np.full(n, 10)]
    # box 1 must not hold the emitter (the emitter is then blocked on its own)
    ok = ~np.all((emitter[:, :2] >= lo1) & (emitter[:, :2] <= hi1), 1)
    bld = _as_buildings(lo[ok], hi[ok], h[ok])
    e, u = emitter[ok].astype(float), uav[ok].astype(float)
    region = np.asarray(_refl_cases_region(bld, e, u).valid[:, 0, 1])
    valid = np.asarray(_refl_cases(bld, e, u).valid[:, 0, 1])
    assert region.sum() > 300
    assert not valid[region].any()


_refl_cases_region = jax.jit(jax.vmap(lambda b, e, u: reflections(b, e, u, check_legs=False),
                                      in_axes=(_PER_CASE, 0, 0)))


def test_line_of_sight_many_boxes_vs_shapely():
    rng = np.random.default_rng(11)
    n, nb = 3000, 6
    lo = rng.uniform(0, 20, (nb, 2))
    hi = lo + rng.uniform(1, 5, (nb, 2))
    h = rng.uniform(2, 12, nb)
    bld = check_buildings(lo, hi, h)
    emitter = np.array([10.0, 10.0, 0.0]) if not np.any(
        np.all((lo <= 10) & (hi >= 10), 1)) else np.array([-3.0, -3.0, 0.0])
    uav = np.concatenate([rng.uniform(-5, 30, (n, 2)), rng.uniform(0, 15, (n, 1))], 1)
    ref = np.zeros(n, bool)
    for j in range(nb):
        ref |= _reference_blocked(np.broadcast_to(emitter, uav.shape), uav,
                                  np.broadcast_to(lo[j], (n, 2)), np.broadcast_to(hi[j], (n, 2)),
                                  np.full(n, h[j]))
    assert 0.1 < ref.mean() < 0.9
    np.testing.assert_array_equal(np.asarray(_shadow_one_layout(bld, emitter, uav)), ref)
    # batch shapes: the unbatched call broadcasts over leading axes as well
    np.testing.assert_array_equal(np.asarray(_shadow(bld, emitter, uav.reshape(50, 60, 3))),
                                  ref.reshape(50, 60))


def test_line_of_sight_conventions():
    """Closed boxes: a segment that only touches a face, an edge or a corner is blocked."""
    b = check_buildings([[0.0, 0.0]], [[2.0, 2.0]], [3.0])  # [0, 2]² × [0, 3]
    blocked = [
        ((-1, 0, 1), (3, 0, 1)),      # runs along the wall y = 0
        ((-1, 1, 3), (3, 1, 3)),      # slides along the roof z = 3
        ((-1, -1, 1), (1, 1, 1)),     # ends inside
        ((2, 2, 3), (5, 5, 9)),       # starts on the top corner (2, 2, 3)
        ((1, 1, 5), (1, 1, 3)),       # vertical, ends on the roof
        ((-1, 1, 1), (1, -1, 1)),     # touches the vertical edge x = y = 0 at (0, 0, 1) only
        ((-1, 1, 4), (1, 1, 2)),      # touches the roof edge x = 0, z = 3 at (0, 1, 3) only
        ((-1, -1, 2), (1, 1, 4)),     # touches the top corner (0, 0, 3) only
    ]
    clear = [
        ((-1, -1e-9, 1), (3, -1e-9, 1)),       # parallel to the wall, just outside
        ((-1, 1, 3 + 1e-7), (3, 1, 3 + 1e-7)),  # parallel to the roof, just above
        ((1, 1, 5), (1, 1, 3.5)),              # vertical, stops above the roof
        ((-1, 1, 1), (1, -1.0001, 1)),         # passes the edge x = y = 0 at y = −5e-5
        ((-1, -1, 2.001), (1, 1, 4.001)),      # passes the top corner just above it
        ((-1, -1, 0), (3, -1, 0)),             # on the ground beside the box
    ]
    a = jnp.asarray([p for p, _ in blocked + clear], float)
    c = jnp.asarray([q for _, q in blocked + clear], float)
    expected = [False] * len(blocked) + [True] * len(clear)
    np.testing.assert_array_equal(np.asarray(_los(b, a, c)), expected)
    np.testing.assert_array_equal(np.asarray(_los(b, c, a)), expected)
    np.testing.assert_array_equal(np.asarray(_shadow(b, a, c)), np.logical_not(expected))
    # no buildings: always clear
    assert bool(_los(_no_buildings(), jnp.zeros(3), jnp.ones(3)))


# --------------------------------------------------------------------------- inside


def test_inside_closed_boxes():
    b = check_buildings([[0.0, 0.0], [5.0, 5.0]], [[2.0, 2.0], [6.0, 8.0]], [3.0, 1.0])
    up = lambda x: float(np.nextafter(x, np.inf))  # noqa: E731
    # one ulp outside the faces at 3, 2, 8 and 1 (nextafter); outside the faces at 0 use a
    # tiny NORMAL number: XLA on the CPU flushes subnormals (−5e-324) to zero
    below0 = -1e-300
    on = [(1, 1, 3), (0, 1, 1), (2, 2, 3), (0, 0, 0), (1, 0, 2), (2, 1, 0), (5.5, 8, 1),
          (6, 5, 0.5)]
    off = [(1, 1, up(3)), (below0, 1, 1), (up(2), 1, 1), (1, 1, below0), (5.5, up(8), 1),
           (4, 4, 0.5), (5.5, 6, up(1))]
    got = np.asarray(_inside(b, jnp.asarray(on + off, float)))
    np.testing.assert_array_equal(got, [True] * len(on) + [False] * len(off))
    assert not bool(_inside(_no_buildings(), jnp.zeros(3)))


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize("lo, hi, height, kw, field", [
    ([[0, 0]], [[1, 1]], [1, 2], {}, "height"),
    ([0, 0], [1, 1], [1], {}, "lo"),
    ([[0, 0]], [[1, 1], [2, 2]], [1], {}, "hi"),
    ([[0, 0]], [[0, 1]], [1], {}, "lo/hi"),
    ([[0, 0]], [[1, -1]], [1], {}, "lo/hi"),
    ([[0, 0]], [[1, 1]], [0], {}, "height"),
    ([[0, 0]], [[1, 1]], [-2], {}, "height"),
    ([[0, np.nan]], [[1, 1]], [1], {}, "lo"),
    ([[0, 0]], [[1, 1]], [np.inf], {}, "height"),
    ([["a", 0]], [[1, 1]], [1], {}, "lo"),
    ([[0, 0]], [[1, 1]], [1], {"R2": 1.5}, "R2"),
    ([[0, 0]], [[1, 1]], [1], {"R2": -0.1}, "R2"),
    ([[0, 0]], [[1, 1]], [1], {"R2": np.nan}, "R2"),
    ([[0, 0]], [[1, 1]], [1], {"R2": [0.5, 0.5]}, "R2"),
])
def test_check_buildings_errors(lo, hi, height, kw, field):
    with pytest.raises(ValueError, match=f"^{field}:"):
        check_buildings(lo, hi, height, **kw)


def test_check_buildings_ok():
    b = check_buildings([[0, 0]], [[1, 2]], [3], R2=0.0)
    assert b.lo.shape == (1, 2) and b.hi.shape == (1, 2) and b.height.shape == (1,)
    assert b.lo.dtype == jnp.float64
    check_buildings([[0, 0]], [[1, 2]], [3], R2=1.0)


# --------------------------------------------------------------------------- shadow (eqs. 7–8)


def test_shadow_is_union_of_eq8_frustums():
    """Eqs. 7–8 with the corrected vertex X_T + l (X_s,i − X_T), l = 50, built as convex
    hulls: inside the truncation distance they coincide with in_shadow; beyond it only
    in_shadow continues."""
    rng = np.random.default_rng(8)
    l_scale = 50.0
    for _ in range(12):
        lo = rng.uniform(0, 10, 2)
        hi = lo + rng.uniform(2, 8, 2)
        h = rng.uniform(5, 20)
        b = check_buildings([lo], [hi], [h])
        while True:
            xt = np.r_[rng.uniform(-15, 35, 2), 0.0]
            if not np.all((xt[:2] >= lo - 1) & (xt[:2] <= hi + 1)):
                break
        walls = [  # (corners, outward signed distance of X_T)
            ([[lo[0], lo[1]], [lo[0], hi[1]]], lo[0] - xt[0]),
            ([[hi[0], lo[1]], [hi[0], hi[1]]], xt[0] - hi[0]),
            ([[lo[0], lo[1]], [hi[0], lo[1]]], lo[1] - xt[1]),
            ([[lo[0], hi[1]], [hi[0], hi[1]]], xt[1] - hi[1]),
        ]
        hulls = []
        for (p, q), dist in walls:
            if dist <= 0:
                continue  # not visible from the emitter
            xs = np.array([[*p, 0], [*q, 0], [*p, h], [*q, h]], float)
            hulls.append(ConvexHull(np.vstack([xs, xt + l_scale * (xs - xt)])).equations)
        # uniform points plus points on rays from the emitter through the box (about half
        # of those lie in the shadow)
        w = np.c_[rng.uniform(lo, hi, (1500, 2)), rng.uniform(0, h, 1500)]
        pts = np.vstack([np.c_[rng.uniform(-60, 90, (1500, 2)), rng.uniform(0, 80, 1500)],
                         xt + rng.uniform(0.3, 4, (1500, 1)) * (w - xt)])
        in_union = np.zeros(len(pts), bool)
        for eq in hulls:
            in_union |= np.all(pts @ eq[:, :3].T + eq[:, 3] <= 1e-9, axis=1)
        got = np.asarray(_shadow_one_layout(b, xt, pts))
        assert 500 < got.sum() < 2500
        np.testing.assert_array_equal(got, in_union)
        # beyond the truncation, behind the box centre: shadow, but outside every frustum
        centre = np.r_[(lo + hi) / 2, h / 2]
        far = xt + 2 * l_scale * (centre - xt)
        assert bool(_shadow(b, xt, far))
        assert not any(np.all(far @ eq[:, :3].T + eq[:, 3] <= 1e-9) for eq in hulls)


# --------------------------------------------------------------------------- NLOS (eqs. 9–10)


def _wall_geometry(lo, hi, h, s):
    """(normal axis, plane coordinate, outward sign, tangential axis, t-extent, height)."""
    axis, sign, tang = [(0, -1, 1), (0, 1, 1), (1, -1, 0), (1, 1, 0)][s]
    c = (lo if sign < 0 else hi)[axis]
    return axis, c, sign, tang, (lo[tang], hi[tang]), h


def test_reflections_vs_path_length_minimisation():
    rng = np.random.default_rng(21)
    n = 300
    lo = np.zeros((n, 2))
    hi = np.c_[rng.uniform(4, 12, n), rng.uniform(4, 12, n)]
    h = rng.uniform(5, 30, n)

    def outside(m, zlo, zhi):
        out = np.empty((m, 3))
        for i in range(m):
            while True:
                xy = rng.uniform(-30, 40, 2)
                if not np.all((xy >= -0.5) & (xy <= hi[i] + 0.5)):
                    break
            out[i] = [*xy, rng.uniform(zlo, zhi)]
        return out

    emitter = outside(n, 0, 0)
    uav = outside(n, 1, 40)
    bld = Buildings(jnp.asarray(lo[:, None]), jnp.asarray(hi[:, None]), jnp.asarray(h[:, None]))
    got = _refl_cases(bld, emitter, uav)
    valid = np.asarray(got.valid)[:, 0]
    point = np.asarray(got.point)[:, 0]
    length = np.asarray(got.length)[:, 0]
    image = np.asarray(got.image)[:, 0]
    n_min = n_valid = n_invalid_faces = n_ambiguous = 0
    for i in range(n):
        e, u = emitter[i], uav[i]
        for s in range(4):
            axis, c, sign, tang, (t_lo, t_hi), hh = _wall_geometry(lo[i], hi[i], h[i], s)
            # mirror image, written out
            e_img = e.copy()
            e_img[axis] = 2 * c - e[axis]
            np.testing.assert_allclose(image[i, s], e_img, rtol=0, atol=1e-12)
            if sign * (e[axis] - c) <= 0 or sign * (u[axis] - c) <= 0:
                assert not valid[i, s]  # the wall does not face both ends
                assert np.isnan(length[i, s]) and np.all(np.isnan(point[i, s]))
                n_invalid_faces += 1
                continue

            def plane_point(v, axis=axis, c=c, tang=tang):
                q = np.empty(3)
                q[axis], q[tang], q[2] = c, v[0], v[1]
                return q

            def path(v):
                q = plane_point(v)
                return np.linalg.norm(e - q) + np.linalg.norm(q - u)

            res = minimize(path, x0=[(t_lo + t_hi) / 2, hh / 2], method="Nelder-Mead",
                           options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000})
            n_min += 1
            v = res.x
            margin = min(v[0] - t_lo, t_hi - v[0], v[1], hh - v[1])
            if abs(margin) > 1e-6:  # unambiguous side of the rectangle boundary
                assert valid[i, s] == (margin > 0), (i, s, margin)
            else:
                n_ambiguous += 1
            if valid[i, s]:
                n_valid += 1
                np.testing.assert_allclose(point[i, s], plane_point(v), atol=1e-6)
                np.testing.assert_allclose(length[i, s], res.fun, rtol=1e-10)
                np.testing.assert_allclose(length[i, s], path([point[i, s][tang], point[i, s][2]]),
                                           rtol=1e-12)
            else:
                assert np.isnan(length[i, s])
    assert n_min > 200 and n_valid > 30 and n_invalid_faces > 200 and n_ambiguous <= 2


def test_reflections_vs_vectorised_minimisation_10000_boxes():
    """The same criterion as above on more than 10,000 random boxes (one emitter and one UAV each, all
    four walls): the shortest emitter→plane→UAV path found by a damped Newton iteration in
    numpy (analytic gradient and Hessian of the two distances — no mirror image) is a valid
    reflection exactly when its minimiser lies on the wall rectangle."""
    rng = np.random.default_rng(22)
    n = 14_000
    lo = rng.uniform(-5, 5, (n, 2))
    hi = lo + rng.uniform(2, 12, (n, 2))
    h = rng.uniform(5, 30, n)
    emitter = np.c_[rng.uniform(-30, 40, (n, 2)), np.zeros(n)]
    uav = np.c_[rng.uniform(-30, 40, (n, 2)), rng.uniform(1, 40, n)]
    keep = ~(np.all((emitter[:, :2] >= lo - 0.5) & (emitter[:, :2] <= hi + 0.5), 1)
             | np.all((uav[:, :2] >= lo - 0.5) & (uav[:, :2] <= hi + 0.5), 1))
    lo, hi, h, emitter, uav = lo[keep], hi[keep], h[keep], emitter[keep], uav[keep]
    m = len(lo)
    bld = Buildings(jnp.asarray(lo[:, None]), jnp.asarray(hi[:, None]), jnp.asarray(h[:, None]))
    valid = np.asarray(_refl_cases(bld, emitter, uav).valid)[:, 0]   # (m, 4)
    checked = ambiguous = n_valid = 0
    for s in range(4):
        axis, sign, tang = [(0, -1, 1), (0, 1, 1), (1, -1, 0), (1, 1, 0)][s]
        c = np.where(sign < 0, lo[:, axis], hi[:, axis])
        t_lo, t_hi = lo[:, tang], hi[:, tang]
        faces = (sign * (emitter[:, axis] - c) > 0) & (sign * (uav[:, axis] - c) > 0)
        assert not np.any(valid[~faces, s])
        # an end within 0.5 of the wall's plane makes the length kinked at the minimiser
        faces &= (np.abs(emitter[:, axis] - c) > 0.5) & (np.abs(uav[:, axis] - c) > 0.5)
        e, u, cc = emitter[faces], uav[faces], c[faces]
        # in-plane coordinates (t, z) of e and u and their distances to the plane
        e2, u2 = np.c_[e[:, tang], e[:, 2]], np.c_[u[:, tang], u[:, 2]]
        de, du = np.abs(e[:, axis] - cc), np.abs(u[:, axis] - cc)

        def length(v):
            return (np.sqrt(np.sum((v - e2) ** 2, 1) + de**2) + np.sqrt(np.sum((v - u2) ** 2, 1) + du**2))

        v = (e2 + u2) / 2
        for _ in range(100):
            grad = np.zeros_like(v)
            hess = np.zeros((len(v), 2, 2))
            for p2, d in ((e2, de), (u2, du)):
                r = v - p2
                norm = np.sqrt(np.sum(r**2, 1) + d**2)
                grad += r / norm[:, None]
                hess += (np.eye(2) - r[:, :, None] * r[:, None, :] / norm[:, None, None] ** 2) / norm[:, None, None]
            step = np.linalg.solve(hess, grad[..., None])[..., 0]
            f0, t = length(v), np.ones(len(v))
            for _ in range(30):  # backtracking: never increase the length
                worse = length(v - t[:, None] * step) > f0 * (1 + 1e-14)  # (rounding of f)
                if not worse.any():
                    break
                t = np.where(worse, t / 2, t)
            v = v - t[:, None] * step
        assert np.max(np.abs(grad)) < 1e-10
        margin = np.minimum.reduce([v[:, 0] - t_lo[faces], t_hi[faces] - v[:, 0], v[:, 1], h[faces] - v[:, 1]])
        clear = np.abs(margin) > 1e-6
        np.testing.assert_array_equal(valid[faces, s][clear], margin[clear] > 0)
        checked += clear.sum()
        ambiguous += (~clear).sum()
        n_valid += valid[faces, s].sum()
    assert m > 10_000 and checked > 10_000 and n_valid > 1000 and ambiguous <= 5


def test_reflection_legs_blocked_by_other_building():
    # wall x = 10 of box 0 reflects towards the UAV; box 1 stands on the first leg
    b = check_buildings([[0.0, 0.0], [14.0, 3.0]], [[10.0, 20.0], [16.0, 7.0]], [30.0, 50.0])
    e = jnp.asarray([20.0, 0.0, 0.0])
    u = jnp.asarray([20.0, 20.0, 10.0])
    with_legs = _refl(b, e, u)
    without = _refl(b, e, u, check_legs=False)
    assert bool(without.valid[0, 1]) and not bool(with_legs.valid[0, 1])
    np.testing.assert_allclose(without.point[0, 1], [10.0, 10.0, 5.0], atol=1e-12)
    np.testing.assert_allclose(without.length[0, 1], math.hypot(20, 20, 10), rtol=1e-14)
    # remove box 1 from the way: valid again
    b2 = check_buildings([[0.0, 0.0], [30.0, -1.0]], [[10.0, 20.0], [32.0, 1.0]], [30.0, 50.0])
    assert bool(_refl(b2, e, u).valid[0, 1])
    # mirror images, written out
    np.testing.assert_allclose(mirror_images(b, e)[0], [[-20, 0, 0], [0, 0, 0], [20, 0, 0],
                                                        [20, 40, 0]], atol=0)


# --------------------------------------------------------------------------- bearing (eqs. 5–6)


def _layout():
    return check_buildings([[40.0, 10.0], [-30.0, 20.0], [0.0, -50.0]],
                           [[60.0, 40.0], [-10.0, 60.0], [30.0, -35.0]], [100.0, 200.0, 40.0],
                           R2=0.5)


def test_bearing_open_field_is_true_bearing():
    rng = np.random.default_rng(1)
    e = np.array([5000.0, 5000.0, 0.0])
    uav = np.c_[rng.uniform(0, 10000, (500, 2)), rng.uniform(100, 400, 500)]
    got = np.asarray(_bearing_one_layout(_no_buildings(), e, uav, 0.5))
    ref = np.array([math.atan2(e[1] - y, e[0] - x) for x, y, _ in uav])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-15)
    # straight above the emitter: 0, like sensors.range_bearing
    assert float(_bearing(_no_buildings(), e, e + np.array([0, 0, 100.0]), 0.5)) == 0.0


def test_bearing_reflectance_zero_and_shadow():
    rng = np.random.default_rng(2)
    b = _layout()
    e = np.array([0.0, 0.0, 0.0])
    uav = np.c_[rng.uniform(-150, 150, (4000, 2)), rng.uniform(5, 220, 4000)]
    los = np.asarray(_los_one_layout(b, e, uav))
    refl = _refl_one_layout(b, e, uav)
    any_refl = np.asarray(jnp.any(refl.valid, axis=(-2, -1)))
    true = np.arctan2(e[1] - uav[:, 1], e[0] - uav[:, 0])
    z0 = np.asarray(_bearing_one_layout(b, e, uav, 0.0))
    z5 = np.asarray(_bearing_one_layout(b, e, uav, 0.5))
    assert los.sum() > 500 and (~los).sum() > 500
    assert (los & any_refl).sum() > 100 and (~los & any_refl).sum() > 50
    assert (~los & ~any_refl).sum() > 50
    # R2 = 0: the LOS bearing wherever LOS exists, NaN otherwise
    np.testing.assert_allclose(z0[los], true[los], rtol=0, atol=1e-14)
    assert np.all(np.isnan(z0[~los]))
    # R2 > 0: NaN exactly in full shadow without a valid reflection
    np.testing.assert_array_equal(np.isnan(z5), ~los & ~any_refl)
    # LOS without reflections: exact; LOS with reflections: biased
    only_los = los & ~any_refl
    np.testing.assert_allclose(z5[only_los], true[only_los], rtol=0, atol=1e-14)
    bias = np.abs(np.angle(np.exp(1j * (z5 - true))))[los & any_refl]
    assert np.all(bias > 0) and np.all(bias < np.pi / 2)
    # shadow with exactly one reflection: the bearing of the reflection point
    one = ~los & (np.asarray(refl.valid).sum(axis=(-2, -1)) == 1)
    assert one.sum() > 20
    pts = np.asarray(refl.point)[one]
    q = pts.reshape(len(pts), -1, 3)[np.isfinite(pts.reshape(len(pts), -1, 3)[..., 0])]
    np.testing.assert_allclose(z5[one], np.arctan2(q[:, 1] - uav[one, 1], q[:, 0] - uav[one, 0]),
                               rtol=0, atol=1e-13)


def test_bearing_field_sum_written_out_and_gradient():
    b = _layout()
    e = jnp.asarray([0.0, 0.0, 0.0])
    u = jnp.asarray([80.0, 5.0, 60.0])  # LOS plus the reflection off y = 10 of box 0
    r = _refl(b, e, u)
    assert bool(_los(b, e, u)) and int(r.valid.sum()) == 1
    img = np.asarray(r.image)[np.asarray(r.valid)][0]
    R2, P, D = 0.5, 1.0, 1.0
    un = np.asarray(u)
    field = 245 * math.sqrt(P * D) * (np.asarray(e) - un) / np.linalg.norm(np.asarray(e) - un) ** 2
    field = field + 245 * math.sqrt(P * D) * R2 * (img - un) / np.linalg.norm(img - un) ** 2
    ref = math.atan2(field[1], field[0])
    assert abs(float(_bearing(b, e, u, R2, P, D)) - ref) < 1e-14
    # P and an omnidirectional D cancel in the bearing
    assert abs(float(_bearing(b, e, u, R2, 7.0, 3.0)) - ref) < 1e-14
    # smooth here: gradient finite and equal to central differences
    f = jax.jit(lambda p: measured_bearing(b, e, p, R2))
    g = np.asarray(jax.jit(jax.grad(f))(u))
    step = 1e-4
    fd = [(float(f(u.at[k].add(step))) - float(f(u.at[k].add(-step)))) / (2 * step)
          for k in range(3)]
    assert np.all(np.isfinite(g))
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-12)
    # finite (zero) gradient straight above the emitter in the open field
    g0 = jax.jit(jax.grad(lambda p: measured_bearing(_no_buildings(), e, p, R2)))(
        jnp.asarray([0.0, 0, 9]))
    assert np.all(np.isfinite(np.asarray(g0)))
