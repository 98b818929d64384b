"""Forward models of the two motions that make paint slide off real bodies: a body turning in depth under a
pinhole camera, and a jumping body whose limbs swing across it. ``bench.motion_scenes`` renders them.

Each model has the interface of the other motion scenes' models: ``surface(t, x, y)`` gives the surface coordinate
(texture pixels) and the anti-aliased coverage at any frame point, ``position(t, uv)`` where a surface point is in
frame ``t`` and whether the camera sees it there, ``color(uv)`` its colour, so a surface point has the same colour in
every frame that shows it. ``texture_size`` is the texture image (one texel per surface unit, texel ``[j, i]`` the
colour at ``(i, j)``) that holds every surface point. Points are ``(x, y)`` with pixel ``[y, x]`` at ``(x, y)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.data.synthetic import _FG_SPOTS, _FG_STRIPES, MIN_BUMP_RADIUS_PX, MIN_WAVELENGTH_PX, _bump

#: Second stripe palette (blue / green), for the surfaces that must not look like the first (orange / magenta).
ALT_STRIPES = np.array([[0.15, 0.30, 0.95], [0.10, 0.80, 0.40]])
#: Third stripe palette (yellow / violet).
THIRD_STRIPES = np.array([[0.95, 0.85, 0.15], [0.45, 0.15, 0.80]])
#: Spot colours beyond ``_FG_SPOTS`` (cyan, yellow): red and near-white.
MORE_SPOTS = np.array([[0.90, 0.12, 0.12], [0.95, 0.95, 0.92]])
#: Query points of the turning body face the camera within this angle (beyond it the surface is foreshortened).
QUERY_FACING_DEG = 60.0


def smooth_coverage(signed_distance: np.ndarray) -> np.ndarray:
    """Anti-aliased coverage from a signed distance in px (> 0 inside): above one half exactly inside."""
    c = np.clip(signed_distance + 0.5, 0.0, 1.0)
    return c * c * (3.0 - 2.0 * c)


def rotate(x: np.ndarray, y: np.ndarray, angle: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(angle), np.sin(angle)
    return c * x - s * y, s * x + c * y


def ellipse_perimeter(a: float, b: float) -> float:
    """Ramanujan's approximation (relative error under 1e-4 for any aspect up to 4): the texture's width, so a texel
    is about a unit of arc round the body's cross-section."""
    return float(np.pi * (3.0 * (a + b) - np.sqrt((3.0 * a + b) * (a + 3.0 * b))))


# --- turning in depth --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _SolidTexture:
    """A texture defined on 3-D body points (so it has no seam round the body): stripes from a few plane waves,
    one palette on the body's -z side and another on its +z side (its two sides look different), and spots."""

    freq: np.ndarray  # [K, 3] radians per px
    phase: np.ndarray  # [K]
    amp: np.ndarray  # [K], summing to 1
    side_scale: float  # z over which the palettes blend (px)
    spots: np.ndarray  # [N, 4]: x, y, z, radius
    spot_rgb: np.ndarray  # [N, 3]

    def color(self, p: np.ndarray) -> np.ndarray:
        s = np.zeros(p.shape[:-1])
        for f, ph, a in zip(self.freq, self.phase, self.amp, strict=True):
            s = s + a * np.sin(p @ f + ph)
        w = (0.5 + 0.5 * s)[..., None]
        side = (0.5 + 0.5 * np.tanh(2.0 * p[..., 2] / self.side_scale))[..., None]
        front = _FG_STRIPES[0] * (1.0 - w) + _FG_STRIPES[1] * w
        back = ALT_STRIPES[0] * (1.0 - w) + ALT_STRIPES[1] * w
        c = front * (1.0 - side) + back * side
        for (cx, cy, cz, r), rgb in zip(self.spots, self.spot_rgb, strict=True):
            d2 = ((p[..., 0] - cx) ** 2 + (p[..., 1] - cy) ** 2 + (p[..., 2] - cz) ** 2) / (r * r)
            g = (np.clip(1.0 - d2, 0.0, None) ** 3)[..., None]
            c = c * (1.0 - g) + rgb * g
        return c


@dataclass(frozen=True)
class TurningDepth:
    """An upright elliptic cylinder (half axes ``half_length`` along body x, ``half_width`` along body z, height
    ``height``) turning about its vertical axis by ``turn`` rad/frame, seen by a pinhole camera at the origin looking
    down +z, level with the body's middle (so neither cap shows). World units are pixels at the axis' depth
    ``distance``, which is also the focal length; the axis drifts sideways by ``drift`` px/frame.

    Surface coordinate: (``radius_mean`` * theta, height from the top), theta the angle of the cross-section's
    parametrisation (a cos theta, b sin theta); u wraps with period ``u_period``. The body is convex, so a point is
    visible exactly where it faces the camera, and the silhouette's sides are the tangent rays from the camera:
    vertical lines in the image, since the camera does not tilt."""

    half_length: float
    half_width: float
    height: float
    distance: float
    axis_x0: float
    drift: float
    turn: float
    principal: tuple[float, float]  # image point of the optical axis
    texture: _SolidTexture
    n_parts: int = 1

    @property
    def u_period(self) -> float:
        return ellipse_perimeter(self.half_length, self.half_width)

    @property
    def radius_mean(self) -> float:
        return self.u_period / (2.0 * np.pi)

    @property
    def texture_size(self) -> tuple[int, int]:
        return int(np.ceil(self.u_period)), int(np.ceil(self.height)) + 1

    def axis(self, t: float) -> tuple[float, float]:
        """The axis' world (x, z) in frame ``t``."""
        return self.axis_x0 + self.drift * t, self.distance

    def camera_in_body(self, t: float) -> tuple[float, float]:
        """The camera's horizontal position in the body's own frame at ``t``: (x, z)."""
        ax, az = self.axis(t)
        px, pz = rotate(np.asarray(-ax), np.asarray(-az), -self.turn * t)
        return float(px), float(pz)

    def _horizon(self, t: float) -> tuple[float, float]:
        """The camera seen from the body, in the cross-section's normalised coordinates: (rho, phi0). A point at
        theta faces the camera where rho * cos(theta - phi0) > 1 (its normal against the direction to it)."""
        px, pz = self.camera_in_body(t)
        qx, qz = px / self.half_length, pz / self.half_width
        return float(np.hypot(qx, qz)), float(np.arctan2(qz, qx))

    def _to_world(self, t: float, bx: np.ndarray, bz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ax, az = self.axis(t)
        wx, wz = rotate(bx, bz, self.turn * t)
        return wx + ax, wz + az

    def _project_x(self, wx: np.ndarray, wz: np.ndarray) -> np.ndarray:
        return self.principal[0] + self.distance * wx / wz

    def facing_cos(self, t: float, uv: np.ndarray) -> np.ndarray:
        """Cosine of the angle between a surface point's normal and the direction to the camera (< 0: back)."""
        theta = uv[..., 0] / self.radius_mean
        bx, bz = self.half_length * np.cos(theta), self.half_width * np.sin(theta)
        nx, nz = rotate(np.cos(theta) / self.half_length, np.sin(theta) / self.half_width, self.turn * t)
        wx, wz = self._to_world(t, bx, bz)
        wy = uv[..., 1] - self.height / 2.0
        dot = -(nx * wx + nz * wz)  # n . (camera - P), camera at the origin, n horizontal
        return np.asarray(dot / (np.hypot(nx, nz) * np.sqrt(wx * wx + wy * wy + wz * wz)))

    def surface(self, t: float, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f, (cx, cy) = self.distance, self.principal
        dx, dy = (x - cx) / f, (y - cy) / f
        a, b = self.half_length, self.half_width
        px, pz = self.camera_in_body(t)
        # the ray's horizontal trace s * (dx, 1) in the body frame: camera + s * e
        ex, ez = rotate(dx, np.ones_like(dx), -self.turn * t)
        qa = ex * ex / (a * a) + ez * ez / (b * b)
        qb = 2.0 * (px * ex / (a * a) + pz * ez / (b * b))
        qc = px * px / (a * a) + pz * pz / (b * b) - 1.0
        # off the body the nearest point of the tangent ray stands in (the coverage there is zero anyway)
        s = (-qb - np.sqrt(np.maximum(qb * qb - 4.0 * qa * qc, 0.0))) / (2.0 * qa)
        bx, bz = px + s * ex, pz + s * ez
        theta = np.arctan2(bz / b, bx / a) % (2.0 * np.pi)
        uv = np.stack((theta * self.radius_mean, s * dy + self.height / 2.0), -1)
        # sides: the tangent points' image columns; top and bottom: the rims at the near hit's depth
        rho, phi0 = self._horizon(t)
        half = float(np.arccos(1.0 / rho))
        tx = a * np.cos(np.array([phi0 - half, phi0 + half]))
        tz = b * np.sin(np.array([phi0 - half, phi0 + half]))
        cols = np.sort(self._project_x(*self._to_world(t, tx, tz)))
        across = np.minimum(x - cols[0], cols[1] - x)
        rim = f * self.height / (2.0 * s)
        along = np.minimum(y - (cy - rim), (cy + rim) - y)
        return uv, smooth_coverage(np.minimum(across, along))

    def position(self, t: float, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        theta = uv[..., 0] / self.radius_mean
        bx, bz = self.half_length * np.cos(theta), self.half_width * np.sin(theta)
        wx, wz = self._to_world(t, bx, bz)
        wy = uv[..., 1] - self.height / 2.0
        xy = np.stack((self._project_x(wx, wz), self.principal[1] + self.distance * wy / wz), -1)
        rho, phi0 = self._horizon(t)
        return xy, rho * np.cos(theta - phi0) > 1.0

    def body_point(self, uv: np.ndarray) -> np.ndarray:
        """The body-frame 3-D point [..., 3] (x, y down, z) of surface coordinate ``uv``."""
        theta = uv[..., 0] / self.radius_mean
        return np.stack(
            (self.half_length * np.cos(theta), uv[..., 1] - self.height / 2.0, self.half_width * np.sin(theta)), -1
        )

    def color(self, uv: np.ndarray) -> np.ndarray:
        return self.texture.color(self.body_point(uv))

    def query_ok(self, t: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Query points face the camera within ``QUERY_FACING_DEG`` (not the foreshortened sides)."""
        return self.facing_cos(t, self.surface(t, x, y)[0]) > np.cos(np.radians(QUERY_FACING_DEG))


def solid_texture(rng: np.random.Generator, half_length: float, half_width: float, height: float) -> _SolidTexture:
    """A seamless texture for an upright elliptic cylinder: three plane waves of wavelength at least twice the
    band limit (foreshortening shortens them in the frame) and spots scattered over the whole side."""
    k = 3
    wavelength = rng.uniform(2.0, 4.0, k) * MIN_WAVELENGTH_PX
    direction = rng.normal(size=(k, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    freq = direction * (2.0 * np.pi / wavelength)[:, None]
    amp = rng.uniform(0.5, 1.0, k)
    n = 16
    theta = (np.arange(n) + rng.uniform(-0.3, 0.3, n)) * 2.0 * np.pi / n
    spots = np.stack(
        (
            half_length * np.cos(theta),
            rng.uniform(-0.4, 0.4, n) * height,
            half_width * np.sin(theta),
            np.maximum(MIN_BUMP_RADIUS_PX, rng.uniform(0.35, 0.6, n) * half_width),
        ),
        -1,
    )
    palette = np.concatenate((_FG_SPOTS, MORE_SPOTS))
    return _SolidTexture(
        freq, rng.uniform(0, 2 * np.pi, k), amp / amp.sum(), half_width, spots, palette[rng.permutation(n) % 4]
    )


# --- limbs and a jump --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Capsule:
    """A rigid part: the disc of ``radius`` swept along a segment of ``length`` from its anchor, down its own axis
    (turned by the part's angle). Its texture region starts at ``offset``: local (a, b) (a across, b along from the
    anchor) is surface coordinate ``offset + (a + radius, b + radius)``."""

    length: float
    radius: float
    offset: tuple[float, float]

    @property
    def extent(self) -> tuple[float, float]:
        return 2.0 * self.radius, self.length + 2.0 * self.radius

    def local(self, anchor: tuple[float, float], angle: float, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
        """Local (a, b) of frame points and their signed distance to the outline (> 0 inside)."""
        a, b = rotate(x - anchor[0], y - anchor[1], -angle)
        along = np.clip(b, 0.0, self.length)
        return a, b, self.radius - np.hypot(a, b - along)

    def uv(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.stack((a + self.radius + self.offset[0], b + self.radius + self.offset[1]), -1)

    def frame_point(self, anchor: tuple[float, float], angle: float, uv: np.ndarray) -> np.ndarray:
        a = uv[..., 0] - self.offset[0] - self.radius
        b = uv[..., 1] - self.offset[1] - self.radius
        x, y = rotate(a, b, angle)
        return np.stack((x + anchor[0], y + anchor[1]), -1)


@dataclass(frozen=True)
class _AtlasTexture:
    """One texture for every part: each part's region (``bounds``: its u range) has its own stripe palette and
    direction; spots anywhere. A texel between regions takes the nearer region's stripes, so the texture is smooth
    over each region and the gap round it."""

    bounds: np.ndarray  # [P, 2]: u0, u1 of each region
    palettes: np.ndarray  # [P, 2, 3]
    stripe_freq: np.ndarray  # [P, 2]
    stripe_phase: np.ndarray  # [P]
    spots: np.ndarray  # [N, 3]: u, v, radius
    spot_rgb: np.ndarray  # [N, 3]

    def region(self, u: np.ndarray) -> np.ndarray:
        cuts = 0.5 * (self.bounds[1:, 0] + self.bounds[:-1, 1])
        return np.searchsorted(cuts, u)

    def color(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        r = self.region(u)
        s = 0.5 + 0.5 * np.sin(self.stripe_freq[r, 0] * u + self.stripe_freq[r, 1] * v + self.stripe_phase[r])
        pal = self.palettes[r]
        c = pal[..., 0, :] * (1.0 - s[..., None]) + pal[..., 1, :] * s[..., None]
        for (cu, cv, rad), rgb in zip(self.spots, self.spot_rgb, strict=True):
            g = _bump(u, v, cu, cv, rad)[..., None]
            c = c * (1.0 - g) + rgb * g
        return c


#: The parts of ``LimbsJump`` (their texture regions in this order) and their order in depth, back to front.
TORSO, FRONT_LIMB, BACK_LIMB = 0, 1, 2
DEPTH_ORDER: tuple[int, ...] = (BACK_LIMB, TORSO, FRONT_LIMB)


@dataclass(frozen=True)
class LimbsJump:
    """An upright torso capsule with two limb capsules hinged near its top, seen side-on (orthographic): the front
    limb swings in front of the torso, the back limb behind it, in opposite phase (they cross, the front one over
    the other), while the whole body jumps in parabolic arcs and drifts. Depth order decides what shows; each part
    has its own region of one texture, so the surface coordinate says which part a pixel shows."""

    parts: tuple[Capsule, Capsule, Capsule]  # torso, front limb, back limb
    start: tuple[float, float]  # torso centre on the ground at frame 0
    drift: float  # px/frame
    jump_height: float
    jump_period: float
    hinge: tuple[float, float]  # front hinge from the torso centre (x, y); the back hinge mirrors x
    swing: float  # amplitude (rad)
    swing_period: float
    texture: _AtlasTexture
    texture_size: tuple[int, int]
    n_parts: int = 3
    u_period: float | None = None

    def centre(self, t: float) -> tuple[float, float]:
        phase = (t % self.jump_period) / self.jump_period
        return self.start[0] + self.drift * t, self.start[1] - 4.0 * self.jump_height * phase * (1.0 - phase)

    def limb_angle(self, t: float) -> float:
        """The front limb's angle from hanging straight down (the back limb's is its negative)."""
        return float(self.swing * np.cos(2.0 * np.pi * t / self.swing_period))

    def pose(self, t: float) -> list[tuple[tuple[float, float], float]]:
        """Each part's anchor and angle in frame ``t``."""
        cx, cy = self.centre(t)
        hx, hy = self.hinge
        phi = self.limb_angle(t)
        return [
            ((cx, cy - self.parts[TORSO].length / 2.0), 0.0),
            ((cx + hx, cy + hy), phi),
            ((cx - hx, cy + hy), -phi),
        ]

    def coverages(self, t: float, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each part's coverage [P, ...] and surface coordinate [P, ..., 2] at frame points, on or off the part."""
        covs, uvs = [], []
        for part, (anchor, angle) in zip(self.parts, self.pose(t), strict=True):
            a, b, dist = part.local(anchor, angle, x, y)
            covs.append(smooth_coverage(dist))
            uvs.append(part.uv(a, b))
        return np.stack(covs), np.stack(uvs)

    @staticmethod
    def _visible(covs: np.ndarray) -> np.ndarray:
        """The part a point shows: the front-most covering its centre, else (on a rim) the most covering."""
        label = np.argmax(covs, axis=0)
        for p in DEPTH_ORDER:  # back to front: a later part covering the centre wins
            label = np.where(covs[p] > 0.5, p, label)
        return label

    def visible_part(self, t: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The part index each frame point shows, -1 off the body (coverage at most one half)."""
        covs, _ = self.coverages(t, x, y)
        alpha = 1.0 - np.prod(1.0 - covs, axis=0)
        return np.where(alpha > 0.5, self._visible(covs), -1)

    def unblended(self, t: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Where frame points show one part's own colour: its coverage is full and no part in front reaches them
        (the composite alpha can be full where a limb's rim blends over the torso)."""
        covs, _ = self.coverages(t, x, y)
        label = self._visible(covs)
        out = np.zeros(np.shape(x), bool)
        for k, part in enumerate(DEPTH_ORDER):
            own = (label == part) & (covs[part] >= 1.0)
            for front in DEPTH_ORDER[k + 1 :]:
                own &= covs[front] <= 0.0
            out |= own
        return out

    def surface(self, t: float, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        covs, uvs = self.coverages(t, x, y)
        label = self._visible(covs)
        uv = np.take_along_axis(uvs, label[None, ..., None], axis=0)[0]
        return uv, 1.0 - np.prod(1.0 - covs, axis=0)

    def composite(
        self, t: float, x: np.ndarray, y: np.ndarray, plate: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The parts over ``plate`` back to front, each with its own anti-aliased coverage."""
        covs, uvs = self.coverages(t, x, y)
        img = plate.copy()
        for p in DEPTH_ORDER:
            inside = covs[p] > 0.0
            if inside.any():
                c = covs[p][inside][:, None]
                img[inside] = c * self.color(uvs[p][inside]) + (1.0 - c) * img[inside]
        label = self._visible(covs)
        uv = np.take_along_axis(uvs, label[None, ..., None], axis=0)[0]
        return img, uv, 1.0 - np.prod(1.0 - covs, axis=0)

    def part_of(self, uv: np.ndarray) -> np.ndarray:
        """Which part a surface coordinate belongs to (by its texture region)."""
        return np.asarray(self.texture.region(uv[..., 0]))

    def position(self, t: float, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        part = self.part_of(uv)
        xy = np.zeros(uv.shape)
        for p, (capsule, (anchor, angle)) in enumerate(zip(self.parts, self.pose(t), strict=True)):
            sel = part == p
            xy[sel] = capsule.frame_point(anchor, angle, uv[sel])
        covs, _ = self.coverages(t, xy[..., 0], xy[..., 1])
        return xy, self._visible(covs) == part

    def color(self, uv: np.ndarray) -> np.ndarray:
        return self.texture.color(uv[..., 0], uv[..., 1])

    def query_ok(self, t: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.ones(np.shape(x), bool)


def atlas_texture(rng: np.random.Generator, parts: tuple[Capsule, ...], spots_per_part: int) -> _AtlasTexture:
    """Stripes of a different palette and direction on each part (the limbs do not look like the torso or each
    other) and spots inside each part's region."""
    bounds = np.array([(p.offset[0], p.offset[0] + p.extent[0]) for p in parts])
    palettes = np.stack((_FG_STRIPES, ALT_STRIPES, THIRD_STRIPES))[: len(parts)]
    angle = rng.uniform(0.2, 1.3, len(parts)) + np.arange(len(parts)) * np.pi / 3.0
    wavelength = np.array([max(MIN_WAVELENGTH_PX * 1.5, 2.0 * p.radius / 2.5) for p in parts])
    freq = np.stack((np.cos(angle), np.sin(angle)), -1) * (2.0 * np.pi / wavelength)[:, None]
    spots, rgb = [], []
    palette = np.concatenate((_FG_SPOTS, MORE_SPOTS))
    for i, p in enumerate(parts):
        h = p.extent[1]
        r = np.maximum(MIN_BUMP_RADIUS_PX, rng.uniform(0.5, 0.8, spots_per_part) * p.radius)
        u = p.offset[0] + p.radius + rng.uniform(-0.5, 0.5, spots_per_part) * p.radius
        v = p.offset[1] + (np.arange(spots_per_part) + rng.uniform(0.2, 0.8, spots_per_part)) * h / spots_per_part
        spots.append(np.stack((u, v, r), -1))
        rgb.append(palette[(np.arange(spots_per_part) + i) % len(palette)])
    return _AtlasTexture(
        bounds, palettes, freq, rng.uniform(0, 2 * np.pi, len(parts)), np.concatenate(spots), np.concatenate(rgb)
    )


__all__ = [
    "DEPTH_ORDER",
    "QUERY_FACING_DEG",
    "Capsule",
    "LimbsJump",
    "TurningDepth",
    "atlas_texture",
    "ellipse_perimeter",
    "rotate",
    "smooth_coverage",
    "solid_texture",
]
