"""Z-buffered rendering of textured planar quads and sprites, with exact optical flow and occlusion masks.

Every surface is a planar quad ``X(a, b) = corner + a * edge_u + b * edge_v`` for ``(a, b)`` in the unit
square, textured so that texel centres sit at integer texture coordinates and the quad spans
``[-0.5, W_t - 0.5] x [-0.5, H_t - 0.5]``. For a plane, both the pixel -> texel map (a homography) and the
inverse depth ``1/Z`` (an affine function of the pixel) are closed-form, so a frame is rendered with one
vectorised pass per surface over its projected bounding box.

Flow is exact: each pixel's 3D point (from its surface's plane) is moved with the rigid motion of that
surface (the camera's for the background, the object's for a sprite) and projected into the other frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .scene import Scene

__all__ = [
    "NEAR",
    "NO_SURFACE",
    "FrameRender",
    "scaled_intrinsics",
    "surface_to_camera",
    "render_frame",
    "lookup",
    "class_motion",
    "exact_flow",
    "occlusion_mask",
]

#: Near clipping distance (world units); points closer than this are not drawn.
NEAR = 0.05
#: Surface index of a pixel that no surface covers.
NO_SURFACE = 255
#: Where the exact bilinear alpha is recomputed around the 0.5 threshold, in 8-bit levels (see
#: ``_sprite_support``).
_ALPHA_REFINE_LEVELS = 24


@dataclass
class FrameRender:
    """One rendered frame.

    ``rgb`` uint8 ``(H, W, 3)``; ``sid`` uint8 ``(H, W)`` index of the visible surface (``NO_SURFACE`` where
    none); ``inv_depth`` float32 ``(H, W)``, ``1/Z`` of the visible point (0 where none); ``planes`` float64
    ``(S, 3)``: surface ``s``'s inverse depth is ``planes[s] . (x, y, 1)`` (NaN for surfaces not drawn);
    ``support`` int64 ``(S,)``: for sprites, the pixels they cover before the depth test (0 for the rest).
    """

    rgb: np.ndarray | None
    sid: np.ndarray
    inv_depth: np.ndarray
    planes: np.ndarray
    support: np.ndarray


def scaled_intrinsics(K: np.ndarray, scale: float) -> np.ndarray:
    """Intrinsics for the image resized by ``scale``, with pixel centres at integer coordinates."""
    S = np.array([[scale, 0.0, 0.5 * scale - 0.5], [0.0, scale, 0.5 * scale - 0.5], [0.0, 0.0, 1.0]])
    return S @ K


def surface_to_camera(scene: "Scene", object_id: int, t: int) -> tuple[np.ndarray, np.ndarray]:
    """Rigid map ``x_cam = A X_local + b`` of frame ``t`` for a surface of ``object_id`` (0 = background)."""
    R, tr = scene.R[t], scene.t[t]
    if object_id == 0:
        return R, tr
    pose = scene.object_poses[object_id - 1, t]
    return R @ pose[:3, :3], R @ pose[:3, 3] + tr


def _clip_near(points: np.ndarray, near: float) -> np.ndarray:
    """Clip a convex polygon (N, 3) in camera coordinates to ``z >= near`` (Sutherland-Hodgman, one plane)."""
    out = []
    n = len(points)
    for i in range(n):
        p, q = points[i], points[(i + 1) % n]
        p_in, q_in = p[2] >= near, q[2] >= near
        if p_in:
            out.append(p)
        if p_in != q_in:
            s = (near - p[2]) / (q[2] - p[2])
            out.append(p + s * (q - p))
    return np.array(out).reshape(-1, 3)


def _bilinear(padded: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Exact bilinear sampling at (u, v) of a float image given with a one-texel zero border (``np.pad(image,
    1)``), so that it is zero outside the image; float64 weights."""
    h, w = padded.shape[0] - 2, padded.shape[1] - 2
    u = u.astype(np.float64)
    v = v.astype(np.float64)
    x0 = np.floor(u)
    y0 = np.floor(v)
    fx = u - x0
    fy = v - y0
    xi = np.clip(x0.astype(np.int64) + 1, 0, w)
    yi = np.clip(y0.astype(np.int64) + 1, 0, h)
    a00 = padded[yi, xi]
    a01 = padded[yi, xi + 1]
    a10 = padded[yi + 1, xi]
    a11 = padded[yi + 1, xi + 1]
    far = (u < -1) | (u > w) | (v < -1) | (v > h)
    value = (a00 * (1 - fx) + a01 * fx) * (1 - fy) + (a10 * (1 - fx) + a11 * fx) * fy
    return np.where(far, 0.0, value)


def _sprite_support(surface, alpha8: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``alpha > 0.5`` at (u, v), exact, given ``alpha8``: the alpha channel that ``cv2.remap`` sampled from the
    uint8 RGBA texture.

    ``cv2.remap`` rounds coordinates to 1/32 texel and works in 8 bits: as alpha changes by at most 255 per
    texel per axis, ``alpha8`` is within 2 * 255/64 + 1 < 10 levels of the exact value. Pixels within
    ``_ALPHA_REFINE_LEVELS`` of the threshold are recomputed exactly from the float alpha, so the decision is
    exact everywhere.
    """
    import cv2

    inside = alpha8 >= 128
    band = cv2.inRange(alpha8, 128 - _ALPHA_REFINE_LEVELS, 127 + _ALPHA_REFINE_LEVELS).view(bool)
    rows, cols = np.nonzero(band)
    if rows.size:
        inside[rows, cols] = _bilinear(surface.alpha_padded, u[rows, cols], v[rows, cols]) > 0.5
    return inside


def lookup(table: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``table[index]`` for a uint8 table of 256 entries and a uint8 index image (``cv2.LUT``: much faster)."""
    import cv2

    return cv2.LUT(index, table.astype(np.uint8, copy=False))


def _frame_geometry(scene: "Scene", t: int, K: np.ndarray):
    """Camera-frame corners, edges and planes of every surface at frame ``t`` (batched over surfaces)."""
    corners, edge_u, edge_v = scene.surface_arrays()
    ids = scene.surface_object_ids()
    X0 = np.empty_like(corners)
    eu = np.empty_like(edge_u)
    ev = np.empty_like(edge_v)
    for k in np.unique(ids):
        sel = ids == k
        A, b = surface_to_camera(scene, int(k), t)
        X0[sel] = corners[sel] @ A.T + b
        eu[sel] = edge_u[sel] @ A.T
        ev[sel] = edge_v[sel] @ A.T
    normal = np.cross(eu, ev)
    dist = np.einsum("ij,ij->i", normal, X0)
    scale = np.linalg.norm(normal, axis=1) * np.maximum(1.0, np.linalg.norm(X0, axis=1))
    usable = np.abs(dist) > 1e-12 * scale  # else edge-on: the camera centre lies in the plane
    with np.errstate(divide="ignore", invalid="ignore"):
        planes = (normal @ np.linalg.inv(K)) / dist[:, None]
    return X0, eu, ev, dist, usable, planes


def render_frame(
    scene: "Scene",
    t: int,
    *,
    K: np.ndarray | None = None,
    size: tuple[int, int] | None = None,
    surfaces: list[int] | None = None,
    color: bool = True,
) -> FrameRender:
    """Render frame ``t`` of ``scene`` (optionally with other intrinsics/size, a subset of surfaces, or
    geometry only when ``color=False``).

    Surfaces are drawn in ``scene.draw_order()`` (objects, then boxes, then the room: roughly front to back),
    so most hidden pixels are rejected by the depth test before their texture coordinates are computed.
    The depth test is strict, so the order only decides exact ties (shared edges).
    """
    import cv2

    K = scene.K if K is None else K
    W, H = scene.size if size is None else size
    xs_all = np.arange(W, dtype=np.float32)
    ys_all = np.arange(H, dtype=np.float32)[:, None]
    inv_near = np.float32(1.0 / NEAR)

    inv_depth = np.zeros((H, W), np.float32)
    sid = np.full((H, W), NO_SURFACE, np.uint8)
    rgba = np.zeros((H, W, 4), np.uint8) if color else None
    rgba32 = rgba.view(np.uint32).reshape(H, W) if color else None
    n_surf = len(scene.surfaces)
    planes = np.full((n_surf, 3), np.nan)
    support = np.zeros(n_surf, np.int64)

    X0s, eus, evs, dists, usable, all_planes = _frame_geometry(scene, t, K)
    quads = np.stack([X0s, X0s + eus, X0s + eus + evs, X0s + evs], axis=1)  # (S, 4, 3)
    order = scene.draw_order()
    if surfaces is not None:
        wanted = set(surfaces)
        order = [i for i in order if i in wanted]
    for i in order:
        s = scene.surfaces[i]
        if not usable[i] or (s.cull_back and dists[i] >= 0):
            continue  # edge-on, or the back face of a closed box
        # bounding box of the projected quad, clipped to the near plane
        poly = quads[i]
        if poly[:, 2].min() < NEAR:
            poly = _clip_near(poly, NEAR)
            if len(poly) == 0:
                continue
        proj = poly @ K.T
        px = proj[:, 0] / proj[:, 2]
        py = proj[:, 1] / proj[:, 2]
        x0 = max(int(np.floor(px.min())) - 1, 0)
        x1 = min(int(np.ceil(px.max())) + 2, W)
        y0 = max(int(np.floor(py.min())) - 1, 0)
        y1 = min(int(np.ceil(py.max())) + 2, H)
        if x0 >= x1 or y0 >= y1:
            continue
        plane = all_planes[i]
        planes[i] = plane
        pl = plane.astype(np.float32)
        is_sprite = s.alpha is not None

        w = pl[0] * xs_all[x0:x1] + (pl[1] * ys_all[y0:y1] + pl[2])
        if not is_sprite:
            # depth test first, then shrink the box to what passes it
            m = w > inv_depth[y0:y1, x0:x1]
            if max(pl[0] * x0, pl[0] * (x1 - 1)) + max(pl[1] * y0, pl[1] * (y1 - 1)) + pl[2] >= inv_near:
                m &= w < inv_near
            rows = np.flatnonzero(m.any(axis=1))
            if rows.size == 0:
                continue
            cols = np.flatnonzero(m.any(axis=0))
            ry0, ry1, rx0, rx1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            m, w = m[ry0:ry1, rx0:rx1], w[ry0:ry1, rx0:rx1]
            y0, y1, x0, x1 = y0 + ry0, y0 + ry1, x0 + rx0, x0 + rx1
        xs = xs_all[x0:x1]
        ys = ys_all[y0:y1]
        tw, th = s.texels
        G = K @ np.column_stack([eus[i], evs[i], X0s[i]])
        Hm = (np.array([[tw, 0.0, -0.5], [0.0, th, -0.5], [0.0, 0.0, 1.0]]) @ np.linalg.inv(G)).astype(np.float32)
        den = Hm[2, 0] * xs + (Hm[2, 1] * ys + Hm[2, 2])
        np.divide(1.0, den, out=den)
        u = Hm[0, 0] * xs + (Hm[0, 1] * ys + Hm[0, 2])
        u *= den
        v = Hm[1, 0] * xs + (Hm[1, 1] * ys + Hm[1, 2])
        v *= den
        if is_sprite:
            if color:  # colour and alpha in one lookup
                col = cv2.remap(s.texture_at(t), u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                alpha8 = np.ascontiguousarray(col[..., 3])
            else:
                alpha8 = cv2.remap(s.alpha8, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            m = _sprite_support(s, alpha8, u, v)
            m &= (w > 0) & (w < inv_near)
            support[i] = np.count_nonzero(m)
            m &= w > inv_depth[y0:y1, x0:x1]
        else:
            m8 = m.view(np.uint8)
            np.bitwise_and(m8, cv2.inRange(u, -0.5, tw - 0.5), out=m8)
            np.bitwise_and(m8, cv2.inRange(v, -0.5, th - 0.5), out=m8)
        if not m.any():
            continue
        np.copyto(inv_depth[y0:y1, x0:x1], w, where=m)
        np.copyto(sid[y0:y1, x0:x1], np.uint8(i), where=m)
        if color:
            if not is_sprite:  # reflect: seamless tiling of a texture smaller than the surface
                col = cv2.remap(s.texture_at(t), u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            np.copyto(rgba32[y0:y1, x0:x1], col.view(np.uint32).reshape(col.shape[:2]), where=m)

    rgb = None
    if color:
        rgb = cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)
        gain = float(scene.brightness[t]) if scene.brightness is not None else 1.0
        if gain != 1.0:
            rgb = np.clip(rgb.astype(np.float32) * np.float32(gain) + np.float32(0.5), 0, 255).astype(np.uint8)
    return FrameRender(rgb=rgb, sid=sid, inv_depth=inv_depth, planes=planes, support=support)


def class_motion(scene: "Scene", object_id: int, t0: int, t1: int) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motion ``x1 = x0 + (A - I) x0 + b`` from camera ``t0`` to camera ``t1`` coordinates of the points
    of ``object_id`` (0 = the static background). Returns ``(A - I, b)``; both are exactly zero when nothing
    moved (a static camera and a still object), so the flow there is exactly zero."""
    if object_id != 0:
        poses = scene.object_poses[object_id - 1]
        if np.array_equal(poses[t0], poses[t1]):
            object_id = 0  # a paused object moves exactly like the background
    A0, b0 = surface_to_camera(scene, object_id, t0)
    A1, b1 = surface_to_camera(scene, object_id, t1)
    if np.array_equal(A0, A1) and np.array_equal(b0, b1):
        return np.zeros((3, 3)), np.zeros(3)
    A = A1 @ A0.T
    return A - np.eye(3), b1 - A @ b0


def _flow_block(M: np.ndarray, e: np.ndarray, xs: np.ndarray, ys: np.ndarray, w: np.ndarray):
    """Flow (fx, fy) and next inverse depth on a block, for ``d = M p + w e`` (see :func:`exact_flow`)."""
    M = M.astype(np.float32)
    e = e.astype(np.float32)
    tmp = np.empty_like(w)
    dz = M[2, 0] * xs + (M[2, 1] * ys + M[2, 2])
    if e[2] != 0:
        dz += np.multiply(w, e[2], out=tmp)
    inv = dz + np.float32(1)  # 1 + d_z
    behind = inv <= 1e-6  # the point ends up behind the camera
    any_behind = bool(behind.any())
    if any_behind:
        inv[behind] = 1e-6
    np.divide(1.0, inv, out=inv)
    out = []
    for row, coord in ((0, xs), (1, ys)):
        d = M[row, 0] * xs + (M[row, 1] * ys + M[row, 2])
        if e[row] != 0:
            d += np.multiply(w, e[row], out=tmp)
        d -= np.multiply(dz, coord, out=tmp)
        d *= inv
        out.append(d)
    w_next = np.multiply(w, inv, out=tmp)
    if any_behind:
        w_next[behind] = -1
    return out[0], out[1], w_next


def exact_flow(
    scene: "Scene", render: FrameRender, t0: int, t1: int, object_of_surface: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Exact flow from frame ``t0`` (whose render is given) to frame ``t1``, and the points' inverse depth
    in frame ``t1``.

    For a pixel p with inverse depth w and class motion (A, b): ``p1 ~ K A K^-1 p + w K b``, written as
    ``p1 = (p + d_xy) / (1 + d_z)`` with ``d = K (A - I) K^-1 p + w K b``, so the flow is
    ``(d_xy - p d_z) / (1 + d_z)``: exactly zero where nothing moved. Returns float32 ``(H, W, 2)`` flow and
    float32 ``(H, W)`` inverse depth ``w / (1 + d_z)`` (-1 where the point ends up behind the camera).
    """
    import cv2

    K = scene.K
    Kinv = np.linalg.inv(K)
    H, W = render.sid.shape
    classes = lookup(object_of_surface, render.sid)
    fx = np.zeros((H, W), np.float32)
    fy = np.zeros((H, W), np.float32)
    w_next = render.inv_depth.copy()
    counts = np.bincount(classes.ravel(), minlength=1)
    for k in range(len(counts)):
        if k and not counts[k]:
            continue
        AmI, b = class_motion(scene, k, t0, t1)
        if not AmI.any() and not b.any():
            continue  # nothing moved: flow 0 and inverse depth unchanged, as initialised
        M = K @ AmI @ Kinv
        e = K @ b
        if k == 0:
            fx[...], fy[...], w_next[...] = _flow_block(M, e, np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)[:, None], render.inv_depth)
            continue
        mask = classes == k
        rows = np.flatnonzero(mask.any(axis=1))
        cols = np.flatnonzero(mask.any(axis=0))
        y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        where = mask[y0:y1, x0:x1]
        bx, by, bw = _flow_block(
            M, e, np.arange(x0, x1, dtype=np.float32), np.arange(y0, y1, dtype=np.float32)[:, None], render.inv_depth[y0:y1, x0:x1]
        )
        np.copyto(fx[y0:y1, x0:x1], bx, where=where)
        np.copyto(fy[y0:y1, x0:x1], by, where=where)
        np.copyto(w_next[y0:y1, x0:x1], bw, where=where)
    return cv2.merge([fx, fy]), w_next


def occlusion_mask(
    flow: np.ndarray, w_next: np.ndarray, render_src: FrameRender, render_dst: FrameRender, *, rel_tol: float = 1e-3
) -> np.ndarray:
    """True where a pixel of the source frame is not visible in the destination frame.

    A pixel is occluded when its flow leaves the image (outside ``[0, W-1] x [0, H-1]``), when its point ends
    up behind the near plane, or when the surface seen at the nearest destination pixel is a different one
    whose plane, evaluated at the exact landing position, lies in front of the point by more than ``rel_tol``
    (relative inverse depth). Conservative by at most a pixel along occluding edges.
    """
    import cv2

    H, W = render_src.sid.shape
    x1 = flow[..., 0] + np.arange(W, dtype=np.float32)
    y1 = flow[..., 1] + np.arange(H, dtype=np.float32)[:, None]
    ok = cv2.inRange(x1, 0, W - 1)
    cv2.bitwise_and(ok, cv2.inRange(y1, 0, H - 1), dst=ok)
    cv2.bitwise_and(ok, cv2.inRange(w_next, 1e-30, 1.0 / NEAR), dst=ok)
    s_dst = cv2.remap(render_dst.sid, x1, y1, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    other = np.logical_and(s_dst != render_src.sid, ok)
    rows, cols = np.nonzero(other)
    occluded = ok == 0
    if rows.size:
        plane = render_dst.planes[s_dst[rows, cols]]
        w_dst = plane[:, 0] * x1[rows, cols] + plane[:, 1] * y1[rows, cols] + plane[:, 2]
        hidden = ~(w_dst <= w_next[rows, cols] * (1 + rel_tol))  # NaN plane (nothing drawn) counts as hidden
        occluded[rows[hidden], cols[hidden]] = True
    return occluded
