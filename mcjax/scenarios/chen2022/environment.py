"""Urban geometry for bearing-only localisation among buildings (Chen & Hao 2022, §1.2).

Buildings are axis-aligned boxes standing on the ground ``z = 0``: box ``j`` is the CLOSED
set ``[lo_jx, hi_jx] × [lo_jy, hi_jy] × [0, height_j]``, so a point on a roof or a wall is
inside it and a segment that only touches a face, an edge or a corner is blocked by it.

What is built here:

* occupancy (Chen & Hao 2022, eq. 3): :func:`inside`;
* the direct path: :func:`line_of_sight` (exact slab test) and :func:`in_shadow`, the
  shadow region of eqs. 7–8;
* one-bounce reflections off the vertical walls (eqs. 9–10): :func:`mirror_images`,
  :func:`reflections`;
* the bearing a direction finder reports (eqs. 5–6): :func:`received_field`,
  :func:`measured_bearing`.

Conventions:

* Every JAX function is pure, jit- and vmap-friendly, and takes points with any leading
  batch shape: ``(..., 3)`` in, ``(...)`` (or ``(..., B, 4, ...)`` per wall) out. The only
  static quantity is the number of buildings ``B`` (``B = 0`` is allowed: open field).
* Walls are numbered per box as ``0: x = lo_x`` (outward normal −x), ``1: x = hi_x`` (+x),
  ``2: y = lo_y`` (−y), ``3: y = hi_y`` (+y). Roofs never reflect (the paper's reflecting
  faces are the walls).
* The slab test divides coordinate differences; IEEE division is correctly rounded and
  monotone, so equal slab parameters stay equal and touching configurations on small-integer
  (or otherwise exactly representable) coordinates are decided exactly. For general floats
  the decision is exact up to the rounding of those quotients (relative 1e-16). XLA would
  rewrite a division by a divisor broadcast over the boxes as a multiplication by its
  reciprocal (not correctly rounded: with two or more boxes a segment through a roof corner
  was called clear); the divisor is kept behind ``jax.lax.optimization_barrier`` so the
  division stays a division.
* Boolean outputs have no gradient; the field and the bearing use
  :func:`mcjax.tracking.numerics.safe_norm`-style double-``where`` guards, so ``jax.grad`` of the
  bearing is finite wherever the set of arriving paths does not change.

``check_buildings`` (numpy) validates inputs once, outside any trace.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

#: Field-strength constant of Chen & Hao 2022, eq. 6 (|E| = 245 √(P D) / r).
FIELD_CONSTANT = 245.0

#: Wall k of a box (module docstring): the axis of its normal (0 = x, 1 = y) ...
WALL_AXIS = (0, 0, 1, 1)
#: ... the sign of its outward normal along that axis ...
WALL_SIGN = (-1.0, 1.0, -1.0, 1.0)
#: ... and its tangential horizontal axis.
WALL_TANGENT = (1, 1, 0, 0)


class Buildings(NamedTuple):
    """Axis-aligned box buildings on the ground (Chen & Hao 2022, eq. 3's ``B_j``).

    ``lo`` (B, 2) and ``hi`` (B, 2) are the footprint corners (x, y) with ``lo < hi``;
    ``height`` (B,) > 0 is the roof height. Box ``j`` is the closed set
    ``[lo_j, hi_j] × [0, height_j]``. Build it with :func:`check_buildings`.
    """

    lo: jax.Array
    hi: jax.Array
    height: jax.Array


class Reflections(NamedTuple):
    """One-bounce reflection paths, one per wall (Chen & Hao 2022, eqs. 9–10).

    ``valid`` (..., B, 4) bool; ``image`` (..., B, 4, 3) the emitter's mirror image in each
    wall's plane; ``point`` (..., B, 4, 3) the reflection point on the wall and ``length``
    (..., B, 4) the path length ``|emitter − point| + |point − uav| = |image − uav|`` —
    both NaN where ``valid`` is False.
    """

    valid: jax.Array
    image: jax.Array
    point: jax.Array
    length: jax.Array


# --------------------------------------------------------------------------- validation


def check_buildings(lo, hi, height, *, R2=None) -> Buildings:
    """Validate a building layout (numpy; call once, outside ``jit``) and return it.

    ``lo``, ``hi`` (B, 2) footprint corners, ``height`` (B,). Raises ``ValueError`` naming
    the offending field for a wrong shape, a non-finite value, a degenerate box
    (``lo >= hi`` on an axis: zero or negative width) or ``height <= 0``. If given, the
    reflectance ``R2`` of eq. 6 must be a finite scalar in [0, 1].
    """
    arrays = {}
    for name, value in (("lo", lo), ("hi", hi), ("height", height)):
        try:
            arrays[name] = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name}: not a numeric array ({exc})") from None
    lo, hi, height = arrays["lo"], arrays["hi"], arrays["height"]
    if lo.ndim != 2 or lo.shape[1] != 2:
        raise ValueError(f"lo: expected shape (B, 2), got {lo.shape}")
    n = lo.shape[0]
    if hi.shape != (n, 2):
        raise ValueError(f"hi: expected shape ({n}, 2) like lo, got {hi.shape}")
    if height.shape != (n,):
        raise ValueError(f"height: expected shape ({n},), got {height.shape}")
    for name, a in (("lo", lo), ("hi", hi), ("height", height)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: non-finite value(s) at box(es) "
                             f"{np.unique(np.nonzero(~np.isfinite(a))[0]).tolist()}")
    bad = np.nonzero(np.any(lo >= hi, axis=1))[0]
    if bad.size:
        raise ValueError(f"lo/hi: degenerate box(es) {bad.tolist()}: need lo < hi on both axes")
    bad = np.nonzero(height <= 0)[0]
    if bad.size:
        raise ValueError(f"height: must be > 0, got {height[bad].tolist()} at box(es) "
                         f"{bad.tolist()}")
    if R2 is not None:
        r2 = np.asarray(R2, dtype=float)
        if r2.shape != () or not np.isfinite(r2) or not 0.0 <= r2 <= 1.0:
            raise ValueError(f"R2: reflectance must be a finite scalar in [0, 1], got {R2!r}")
    return Buildings(jnp.asarray(lo), jnp.asarray(hi), jnp.asarray(height))


# --------------------------------------------------------------------------- helpers


def boxes3(b: Buildings):
    """3-D corners ``lo3``, ``hi3`` (B, 3) of the closed boxes (the buildings of eq. 3)."""
    lo = jnp.asarray(b.lo)
    hi = jnp.asarray(b.hi)
    h = jnp.asarray(b.height)
    lo3 = jnp.concatenate([lo, jnp.zeros_like(h)[:, None]], axis=-1)
    hi3 = jnp.concatenate([hi, h[:, None]], axis=-1)
    return lo3, hi3


def _segment_hits(a: jax.Array, c: jax.Array, lo3: jax.Array, hi3: jax.Array) -> jax.Array:
    """Slab test: does the closed segment ``a–c`` meet the closed box ``[lo3, hi3]``?

    All arguments broadcast over leading axes, last axis 3. Returns the broadcast shape
    without the last axis. Axis ``k`` restricts the segment parameter t ∈ [0, 1] to
    ``[(lo−a)/d, (hi−a)/d]`` (ordered); a direction with ``d_k = 0`` either keeps every t
    (the segment lies within the slab) or none. Hit iff the intersection is non-empty
    (closed: a single touching point counts).
    """
    d = c - a
    zero = d == 0
    shape = jnp.broadcast_shapes(a.shape, c.shape, lo3.shape, hi3.shape)
    # the divisor at the quotients' full shape, behind an optimisation barrier: XLA rewrites
    # ``x / broadcast(d)`` as ``x * broadcast(1 / d)``, which is not correctly rounded
    # (−98 · (1/−196) = 0.49999999999999994), and equal slab parameters would then differ
    safe = jax.lax.optimization_barrier(jnp.broadcast_to(jnp.where(zero, 1.0, d), shape))
    t1 = (lo3 - a) / safe
    t2 = (hi3 - a) / safe
    in_slab = (a >= lo3) & (a <= hi3)
    inf = jnp.asarray(jnp.inf, t1.dtype)
    t_lo = jnp.where(zero, jnp.where(in_slab, -inf, inf), jnp.minimum(t1, t2))
    t_hi = jnp.where(zero, jnp.where(in_slab, inf, -inf), jnp.maximum(t1, t2))
    t_enter = jnp.maximum(jnp.max(t_lo, axis=-1), 0.0)
    t_exit = jnp.minimum(jnp.min(t_hi, axis=-1), 1.0)
    return t_enter <= t_exit


def inv_sq_field(vec: jax.Array, amplitude) -> jax.Array:
    """``amplitude · vec / |vec|²``: a field of magnitude ``amplitude / |vec|`` pointing
    along ``vec`` (eq. 6's 1/r decay). Zero, with a zero gradient, at ``vec = 0``."""
    sq = jnp.sum(vec * vec, axis=-1, keepdims=True)
    positive = ~(sq <= 0.0)
    safe_sq = jnp.where(positive, sq, 1.0)
    return jnp.where(positive, amplitude[..., None] * vec / safe_sq, 0.0)


# --------------------------------------------------------------------------- occupancy, LOS


def inside(buildings: Buildings, p: jax.Array) -> jax.Array:
    """True where ``p`` (..., 3) lies in any (closed) building: ``p ∈ A_Build``
    (Chen & Hao 2022, eq. 3). Roof and wall points count as inside. Returns (...)."""
    p = jnp.asarray(p)
    lo3, hi3 = boxes3(buildings)
    q = p[..., None, :]
    return jnp.any(jnp.all((q >= lo3) & (q <= hi3), axis=-1), axis=-1)


def line_of_sight(buildings: Buildings, a: jax.Array, b: jax.Array) -> jax.Array:
    """True where the segment ``a–b`` (..., 3) meets no building (exact slab test).

    Closed-box convention: a segment that only touches a wall, a roof, an edge or a corner,
    or that has an end point on or inside a building, is BLOCKED (returns False).
    Returns (...). No buildings (B = 0): always True.
    """
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    lo3, hi3 = boxes3(buildings)
    hits = _segment_hits(a[..., None, :], b[..., None, :], lo3, hi3)
    return ~jnp.any(hits, axis=-1)


def in_shadow(buildings: Buildings, emitter: jax.Array, uav: jax.Array) -> jax.Array:
    """True where ``uav`` (..., 3) lies in the signal shadow ``A_Shadow`` of ``emitter``
    (Chen & Hao 2022, eqs. 7–8): exactly ``~line_of_sight(buildings, emitter, uav)``.

    Relation to eqs. 7–8. ``A_Shadow,s`` is the polyhedron with vertices ``X_s,i`` (the
    corners of a face s visible from the emitter ``X_T``) and ``X_T + l (X_s,i − X_T)``
    (eq. 8 prints ``l (X_s,i − X_T)``, which drops the ``X_T +``). That polyhedron is the
    frustum ``{X_T + t (w − X_T) : w ∈ face s, 1 ≤ t ≤ l}``, i.e. the points whose segment
    from ``X_T`` crosses face s, cut off at ``l`` times the distance to the face. A ray
    enters a convex box through a face that faces the emitter, so the union over a box's
    visible faces is the set of points whose segment from ``X_T`` meets the box — eq. 7's
    union is therefore this function truncated at scale ``l``. Here ``l = ∞`` (no
    truncation; the paper's ``l = 50`` only serves to make the region "far enough"). Closed
    faces make both sets closed, so a UAV on a wall or a roof is in the shadow. For an
    emitter on the ground only the four walls can be visible; for a raised emitter the
    roof is included automatically by the slab test.
    """
    return ~line_of_sight(buildings, emitter, uav)


# --------------------------------------------------------------------------- reflections


def wall_frame(buildings: Buildings):
    """The walls of every box (eqs. 9–10; numbered as in the module docstring): ``(c, t_lo, t_hi,
    hh)``, each (B, 4): the coordinate of the wall's plane along its normal (:data:`WALL_AXIS`),
    its tangential extent along :data:`WALL_TANGENT`, and its height (the roof's)."""
    lo = jnp.asarray(buildings.lo)
    hi = jnp.asarray(buildings.hi)
    h = jnp.asarray(buildings.height)
    c = jnp.stack([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]], axis=-1)
    t_lo = jnp.stack([lo[:, 1], lo[:, 1], lo[:, 0], lo[:, 0]], axis=-1)
    t_hi = jnp.stack([hi[:, 1], hi[:, 1], hi[:, 0], hi[:, 0]], axis=-1)
    hh = jnp.broadcast_to(h[:, None], c.shape)
    return c, t_lo, t_hi, hh


def per_wall(p: jax.Array, axes) -> jax.Array:
    """``p[..., axes]`` (..., 3) -> (..., 1, 4): for each wall k of a box, the coordinate
    ``axes[k]`` of ``p`` (``axes``: :data:`WALL_AXIS` or :data:`WALL_TANGENT`), broadcast over
    the boxes."""
    return jnp.stack([p[..., k] for k in axes], axis=-1)[..., None, :]


def mirror_images(buildings: Buildings, emitter: jax.Array) -> jax.Array:
    """The emitter's mirror image ``X'_T,s`` in the plane of every wall (Chen & Hao 2022,
    eq. 10). ``emitter`` (..., 3) -> (..., B, 4, 3): for a wall ``x = c`` the image is
    ``(2c − x, y, z)``, for ``y = c`` it is ``(x, 2c − y, z)``."""
    emitter = jnp.asarray(emitter)
    c, _, _, _ = wall_frame(buildings)
    x = emitter[..., 0][..., None, None]
    y = emitter[..., 1][..., None, None]
    z = emitter[..., 2][..., None, None]
    normal_x = jnp.asarray([True, True, False, False])
    ix = jnp.where(normal_x, 2.0 * c - x, x)
    iy = jnp.where(normal_x, y, 2.0 * c - y)
    iz = jnp.broadcast_to(z, ix.shape)
    return jnp.stack([ix, iy, iz], axis=-1)


def _reflections_raw(buildings: Buildings, emitter, uav, check_legs: bool):
    """Reflection geometry with safe (finite) values on invalid walls."""
    emitter = jnp.asarray(emitter)
    uav = jnp.asarray(uav)
    c, t_lo, t_hi, hh = wall_frame(buildings)
    sign = jnp.asarray(WALL_SIGN, dtype=c.dtype)
    # signed distances to each wall plane, positive on the wall's outward side
    d_e = sign * (per_wall(emitter, WALL_AXIS) - c)
    d_u = sign * (per_wall(uav, WALL_AXIS) - c)
    faces_both = (d_e > 0) & (d_u > 0)
    denom = jnp.where(faces_both, d_e + d_u, 1.0)
    # the segment image→uav crosses the plane at fraction d_e/(d_e + d_u) from the image,
    # where the tangential and vertical coordinates interpolate those of emitter and uav
    frac = jnp.where(faces_both, d_e / denom, 0.5)
    e_t, u_t = per_wall(emitter, WALL_TANGENT), per_wall(uav, WALL_TANGENT)
    e_z, u_z = emitter[..., 2][..., None, None], uav[..., 2][..., None, None]
    q_t = e_t + frac * (u_t - e_t)
    q_z = e_z + frac * (u_z - e_z)
    on_wall = (q_t >= t_lo) & (q_t <= t_hi) & (q_z >= 0.0) & (q_z <= hh)
    valid = faces_both & on_wall
    normal_x = jnp.asarray([True, True, False, False])
    c_b = jnp.broadcast_to(c, q_t.shape)
    point = jnp.stack([jnp.where(normal_x, c_b, q_t), jnp.where(normal_x, q_t, c_b), q_z], -1)
    image = mirror_images(buildings, emitter)
    if check_legs:
        lo3, hi3 = boxes3(buildings)
        n_b = lo3.shape[0]
        e_b = jnp.broadcast_to(emitter[..., None, None, :], point.shape)
        u_b = jnp.broadcast_to(uav[..., None, None, :], point.shape)
        leg1 = _segment_hits(e_b[..., None, :], point[..., None, :], lo3, hi3)  # (..., B, 4, B)
        leg2 = _segment_hits(point[..., None, :], u_b[..., None, :], lo3, hi3)
        # both legs lie strictly on the outward side of their own wall except at the
        # reflection point, so their own box is excluded exactly
        other = ~jnp.eye(n_b, dtype=bool)[:, None, :]
        blocked = jnp.any((leg1 | leg2) & other, axis=-1)
        valid = valid & ~blocked
    return valid, image, point


def reflections(buildings: Buildings, emitter: jax.Array, uav: jax.Array,
                check_legs: bool = True) -> Reflections:
    """One-bounce reflection paths emitter → wall → uav (Chen & Hao 2022, eqs. 9–10).

    ``emitter``, ``uav`` (..., 3) -> :class:`Reflections` with per-wall arrays (..., B, 4).
    Wall s reflects iff

    1. both the emitter and the UAV lie strictly on the wall's outward side (the wall is
       "visible" from both; a point in the wall's plane does not count), and
    2. the segment from the mirror image ``X'_T,s`` to the UAV crosses the closed wall
       rectangle (tangential extent of the footprint, ``0 ≤ z ≤ height``) — the NLOS region
       ``A_NLOS,s`` of eqs. 9–10 with ``l = ∞`` (same reading as :func:`in_shadow`), and
    3. if ``check_legs`` (static, default True): neither leg emitter→point nor point→uav
       meets any OTHER building (closed convention: touching blocks). The reflecting box
       itself can only touch the legs at the reflection point, so it is not tested. With
       ``check_legs=False`` this is exactly the paper's region membership ``uav ∈ A_NLOS,s``.

    The reflection point minimises the path length over the wall's plane (Fermat); the
    path length equals ``|X'_T,s − uav|``.
    """
    valid, image, point = _reflections_raw(buildings, emitter, uav, check_legs)
    length = jnp.sqrt(jnp.sum((image - jnp.asarray(uav)[..., None, None, :]) ** 2, -1))
    nan = jnp.asarray(jnp.nan, point.dtype)
    return Reflections(valid, image, jnp.where(valid[..., None], point, nan),
                       jnp.where(valid, length, nan))


# --------------------------------------------------------------------------- bearing


def received_field(buildings: Buildings, emitter: jax.Array, uav: jax.Array, R2,
                   P=1.0, D=1.0, check_legs: bool = True):
    """Summed field ``E = E_LOS + Σ_s E_NLOS,s`` at the UAV (Chen & Hao 2022, eqs. 5–6).

    Each path contributes a 3-D vector pointing from the UAV along its arrival direction —
    towards the emitter for the direct path, towards the mirror image (= the reflection
    point) for wall s — with magnitude ``245 √(P D) / r_LOS`` resp.
    ``245 √(P D) R2 / r_NLOS,s`` (eq. 6; ``r_NLOS,s`` is the full two-leg path length). The
    direct path counts only with line of sight, wall s only when
    ``reflections(...).valid``. ``D`` is one directivity for every direction (the paper's
    omnidirectional antenna, ``D = 1``). ``emitter``, ``uav`` (..., 3).

    Returns ``(field (..., 3), arrived (...))``; ``arrived`` is True when at least one path
    reaches the UAV with a non-zero amplitude (LOS, or a valid reflection with ``R2 > 0``).
    """
    emitter = jnp.asarray(emitter)
    uav = jnp.asarray(uav)
    dtype = jnp.result_type(emitter, uav, float)
    k = FIELD_CONSTANT * jnp.sqrt(jnp.asarray(P, dtype) * jnp.asarray(D, dtype))
    r2 = jnp.asarray(R2, dtype)
    los = line_of_sight(buildings, emitter, uav)
    e_los = inv_sq_field(emitter - uav, jnp.where(los, k, 0.0))
    valid, image, _ = _reflections_raw(buildings, emitter, uav, check_legs)
    amp = jnp.where(valid, k * r2, 0.0)
    e_nlos = inv_sq_field(image - uav[..., None, None, :], amp)
    field = e_los + jnp.sum(e_nlos, axis=(-3, -2))
    arrived = los | (jnp.any(valid, axis=(-2, -1)) & (r2 > 0))
    return field, arrived


def measured_bearing(buildings: Buildings, emitter: jax.Array, uav: jax.Array, R2,
                     P=1.0, D=1.0, check_legs: bool = True) -> jax.Array:
    """Noise-free bearing the UAV measures: the azimuth ``atan2(E_y, E_x)`` of the summed
    field of :func:`received_field` (Chen & Hao 2022, eqs. 5–6; eq. 2's ``η`` with the
    four-quadrant arctan).

    ``emitter``, ``uav`` (..., 3) -> (...), in (−π, π]. NaN (no measurement) where nothing
    arrives: the UAV is in the shadow and no wall reflects (or ``R2 = 0``). With line of
    sight and no reflections it is the true bearing of eq. 2. A zero horizontal field (UAV
    straight above the emitter) gives 0 with a zero gradient, as
    :func:`mcjax.tracking.models.sensors.range_bearing`. ``P`` and a direction-independent ``D``
    scale every path alike, so they do not change the bearing. Validate ``R2`` with
    :func:`check_buildings` (``R2=``).
    """
    field, arrived = received_field(buildings, emitter, uav, R2, P, D, check_legs)
    ex, ey = field[..., 0], field[..., 1]
    zero = (ex == 0.0) & (ey == 0.0)
    bearing = jnp.where(zero, 0.0, jnp.arctan2(ey, jnp.where(zero, 1.0, ex)))
    bearing = jnp.where(bearing == -jnp.pi, jnp.pi, bearing)  # atan2(−0, x < 0) = −π
    return jnp.where(arrived, bearing, jnp.nan)
