"""Ray-traced hard-shadow visibility: the ground truth the shadow-map renderer is measured against.

For every pixel a primary ray finds the visible surface; for every light a shadow ray from that
surface says whether anything that casts shadows lies between the surface and the light. No
filtering, no bias tuning: what a perfect shadow map would give.

All tracing happens in a normalised frame (the render's origin at the origin: the scene's centre,
or a point beside the eye of a close view of a vast scene; bounding-box diagonal 1), computed in
float64 before anything reaches embree's float32 BVH. That keeps the result the same whether the
scene is millimetres wide or sits 1e5 units away from the origin.

Shadow rays start just off their surface by an offset relative to the local geometry, not to the
scene: a few float32 steps of the surface triangle's own coordinates (what embree's copy of it
may be off by), or a hundredth of the pixel's footprint where that is larger. A fixed fraction
of the scene would lift the rays off a 10,000-unit plane by a tenth of a unit and hide the
shadow of a 1-unit box from the truth. A shadow ray never counts its own triangle as a hit (it
leaves a plane and cannot meet it again).

Triangles that can never stop a ray of a kind (BLEND surfaces for primary rays, non-casters for
shadow rays, untextured cut-outs whose constant alpha fails the test) are left out of that kind's
BVH, so the only hits that need a second look are textured or vertex-coloured MASK/BLEND triangles;
those are alpha-tested at the hit and the ray continues past them a bounded number of times.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import Camera, view_origin
from .errors import ReferenceUnavailable, RequestError
from .lights import Light
from .plan.geometry import FACING_COS
from .scene import (
    BLEND_SHADOW_CUTOFF,
    CLAMP_TO_EDGE,
    MIRRORED_REPEAT,
    NEAREST,
    Sampler,
    Scene,
)

#: Continuation step of primary rays through cut-outs, as a fraction of the scene diagonal.
EPS_REL = 1e-5
#: Shadow-ray offset: float32 steps (2**-24 of the largest coordinate) of the surface triangle.
EPS_ULPS = 16.0
#: Shadow-ray offset: at least this fraction of the pixel's footprint on the surface.
EPS_PIXEL = 1e-2
#: Most alpha-tested surfaces a ray may pass through before it is given up. Such a pixel is
#: reported rather than guessed: as no geometry (primary ray) or as not valid (shadow ray).
MAX_LAYERS = 8

_OPAQUE, _MASK, _BLEND = 0, 1, 2


@dataclass
class ReferenceResult:
    """Ray-traced shadow visibility of one view.

    Attributes
    ----------
    visibility : ndarray, shape (H, W, L), float32
        1 where light ``l`` reaches the pixel's surface, 0 where it is blocked, NaN where the pixel
        shows no geometry.
    valid : ndarray, shape (H, W, L), bool
        The pixel shows geometry that receives shadows, faces light ``l`` and lies inside its spot
        cone and range: the pixels where a shadow comparison means something.
    depth : ndarray, shape (H, W), float32
        Camera-space depth (distance along the camera's −Z) of the visible surface; NaN where
        the pixel shows none.
    seconds : float
        Wall time of the trace.
    """

    visibility: np.ndarray
    valid: np.ndarray
    depth: np.ndarray
    seconds: float


def _embree() -> tuple[Any, Any]:
    """embreex's scene and triangle-mesh classes; refuses a missing embreex (there is no fast
    fallback)."""
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as exc:
        raise ReferenceUnavailable(
            "the ray-traced reference needs embreex: pip install 'shadowmap-service[reference]' "
            f"(or pip install embreex); import failed with: {exc}"
        ) from None
    return rtcore_scene.EmbreeScene, TriangleMesh


def _wrapped(i: np.ndarray, size: int, wrap: int) -> np.ndarray:
    """Texel indices ``i`` (int64) wrapped into ``[0, size)`` as GL wraps them."""
    if wrap == CLAMP_TO_EDGE:
        return np.clip(i, 0, size - 1)
    if wrap == MIRRORED_REPEAT:  # period 2 * size: 0 .. size - 1, then size - 1 .. 0
        m = i % (2 * size)
        return np.where(m < size, m, 2 * size - 1 - m)
    return i % size


def _texel_alpha(texture: np.ndarray, uv: np.ndarray, sampler: Sampler
                 ) -> np.ndarray:
    """Alpha at ``uv`` as the renderer samples cut-outs: level 0, through the material's
    sampler (its magnification filter, bilinear or nearest, and its wrap modes).

    Both passes test alpha with ``textureLod(..., 0.0)``, which reads level 0 through the
    magnification filter, so with ``LINEAR`` the edge of a cut-out is where the bilinear
    interpolation of its texels crosses the cutoff; a nearest-texel truth would put that edge up
    to half a texture texel elsewhere.

    Parameters
    ----------
    texture : ndarray, shape (TH, TW, 4), uint8
        Rows top to bottom, as in the image file.
    uv : ndarray, shape (M, 2)
        :attr:`Primitive.uv`. trimesh flips glTF's ``v`` on load (``v = 1 - TEXCOORD_0.v``), so
        here ``v = 1`` is the top image row; this is the file's own glTF mapping undone.
    sampler : Sampler

    Returns
    -------
    ndarray, shape (M,), float64 in [0, 1]
    """
    th, tw = texture.shape[:2]
    a = texture[..., 3]
    # Texel centres sit at half-integers (GL's convention): x = u * W - 0.5 between columns.
    # GL's v = 0 is the bottom row: row (from the top) th - 1 - y. Wrapping applies to GL's
    # indices, so it is taken on those (a mirror is the same from either end, a clamp too).
    x = uv[:, 0] * tw
    y = uv[:, 1] * th
    if sampler.mag_filter == NEAREST:
        c = _wrapped(np.floor(x).astype(np.int64), tw, sampler.wrap_s)
        r = _wrapped(np.floor(y).astype(np.int64), th, sampler.wrap_t)
        return a[th - 1 - r, c] / 255.0
    x, y = x - 0.5, y - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    c0 = _wrapped(x0.astype(np.int64), tw, sampler.wrap_s)
    c1 = _wrapped(x0.astype(np.int64) + 1, tw, sampler.wrap_s)
    r0 = th - 1 - _wrapped(y0.astype(np.int64), th, sampler.wrap_t)
    r1 = th - 1 - _wrapped(y0.astype(np.int64) + 1, th, sampler.wrap_t)
    low = a[r0, c0] * (1.0 - fx) + a[r0, c1] * fx
    high = a[r1, c0] * (1.0 - fx) + a[r1, c1] * fx
    return (low * (1.0 - fy) + high * fy) / 255.0


class _Bvh:
    """An embree BVH over a subset of the scene's triangles, answering in global face indices.

    Built on embreex directly, with the triangles in the tracer's frame as they are: trimesh's
    wrapper moves every coordinate to the mesh's lowest corner first, which undoes a frame
    centred beside the eye (a close view of a vast scene)."""

    def __init__(self, tri: np.ndarray, faces: np.ndarray) -> None:
        self.faces = faces
        self._scene: Any = None
        if len(faces) == 0:
            return
        scene_cls, mesh_cls = _embree()
        verts = np.ascontiguousarray(tri[faces].reshape(-1, 3), np.float32)
        self._scene = scene_cls()
        mesh_cls(scene=self._scene, vertices=verts,
                 indices=np.arange(len(verts), dtype=np.int32).reshape(-1, 3))

    def first(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Global index of the nearest triangle hit, -1 for a miss; shape (N,)."""
        if self._scene is None or len(origins) == 0:
            return np.full(len(origins), -1, np.int64)
        local = np.asarray(self._scene.run(np.ascontiguousarray(origins, np.float32),
                                           np.ascontiguousarray(directions, np.float32)),
                           np.int64)
        out = np.full(len(origins), -1, np.int64)
        hit = local >= 0
        out[hit] = self.faces[local[hit]]
        return out


class _Tracer:
    """The scene's triangles in the normalised frame, with per-face material data and BVHs."""

    def __init__(self, scene: Scene, centre: np.ndarray | None = None) -> None:
        _embree()  # refused before any work when embreex is missing
        lo, hi = scene.bounds
        self.centre = (lo + hi) / 2 if centre is None else np.asarray(centre, np.float64)
        diag = float(np.linalg.norm(hi - lo))
        self.diag = diag if np.isfinite(diag) and diag > 0 else 1.0
        self.eps = EPS_REL

        tris, inst_of, local_of = [], [], []
        for k, inst in enumerate(scene.instances):
            # Placed relative to the centre: subtracted after placing, a small part far from the
            # world's origin would keep only its world coordinates' float64 steps.
            t = scene.world_triangles(inst, self.centre)
            tris.append(t / self.diag)
            inst_of.append(np.full(len(t), k, np.int64))
            local_of.append(np.arange(len(t), dtype=np.int64))
        self.tri = np.concatenate(tris)  # (F, 3, 3) float64, normalised frame
        self.face_inst = np.concatenate(inst_of)
        self.face_local = np.concatenate(local_of)
        self.scene = scene

        e1 = self.tri[:, 1] - self.tri[:, 0]
        e2 = self.tri[:, 2] - self.tri[:, 0]
        n = np.cross(e1, e2)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        self.normal = np.divide(n, length, out=np.zeros_like(n), where=length > 0)

        prims = scene.primitives
        inst_prim = np.array([i.primitive for i in scene.instances], np.int64)
        self.face_prim = inst_prim[self.face_inst]
        mode_code = {"OPAQUE": _OPAQUE, "MASK": _MASK, "BLEND": _BLEND}
        p_mode = np.array([mode_code.get(p.material.alpha_mode, _OPAQUE) for p in prims], np.int64)
        # Back faces the camera pass culls: single-sided materials but BLEND (drawn from both
        # sides). The front side follows the winding, reversed by a mirroring node (glTF: a
        # negative determinant winds its faces clockwise; the camera pass turns glFrontFace).
        p_cull = np.array([not p.material.double_sided and p.material.alpha_mode != "BLEND"
                           for p in prims], bool)
        self.cull_back = p_cull[self.face_prim]
        mirrored = np.array([np.linalg.det(i.matrix[:3, :3]) < 0 for i in scene.instances], bool)
        self.front = np.where(mirrored[self.face_inst][:, None], -self.normal, self.normal)
        p_cut = np.array([p.material.alpha_cutoff for p in prims], np.float64)
        p_base = np.array([float(p.material.base_color[3]) for p in prims], np.float64)
        p_vary = np.array(
            [p.material.texture is not None and p.uv is not None or p.colors is not None
             for p in prims], bool,
        )
        mode = p_mode[self.face_prim]
        base = p_base[self.face_prim]
        vary = p_vary[self.face_prim] & (mode != _OPAQUE)
        cast = np.array([i.cast_shadow for i in scene.instances], bool)[self.face_inst]
        self.receive_inst = np.array([i.receive_shadow for i in scene.instances], bool)

        # Alpha a hit must reach to count: primary rays stop on MASK surfaces at the cutoff;
        # shadow rays are stopped by MASK surfaces at the cutoff and by BLEND ones at
        # BLEND_SHADOW_CUTOFF (as the light pass does: Material.shadow_cutoff).
        cut = p_cut[self.face_prim]
        self.primary_threshold = np.where(mode == _MASK, cut, 0.0)
        self.shadow_threshold = np.where(mode == _MASK, cut,
                                         np.where(mode == _BLEND, BLEND_SHADOW_CUTOFF, 0.0))
        self.primary_test = vary & (mode == _MASK)
        self.shadow_test = vary & cast
        primary_in = (mode == _OPAQUE) | ((mode == _MASK) & (vary | (base >= cut)))
        shadow_in = cast & ((mode == _OPAQUE) | vary | (base >= self.shadow_threshold))

        pf = np.flatnonzero(primary_in)
        sf = np.flatnonzero(shadow_in)
        self.primary_bvh = _Bvh(self.tri, pf)
        # Most scenes have no BLEND surfaces and no non-casters: share one BVH then.
        self.shadow_bvh = self.primary_bvh if np.array_equal(pf, sf) else _Bvh(self.tri, sf)

    # ---------------------------------------------------------------------------------------

    def intersect(self, faces: np.ndarray, o: np.ndarray,
                  d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact float64 ray-triangle intersection with known triangles (Möller–Trumbore).

        Returns
        -------
        t : ndarray, shape (M,)
            Distance along each (unit) ray in the normalised frame.
        bary : ndarray, shape (M, 2)
            Weights of vertices 1 and 2 at the hit, clamped into the triangle.
        """
        tri = self.tri[faces]
        e1 = tri[:, 1] - tri[:, 0]
        e2 = tri[:, 2] - tri[:, 0]
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-300
        inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        s = o - tri[:, 0]
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = np.einsum("ij,ij->i", d, q) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        if not ok.all():  # embree hit a triangle float64 calls edge-on: use its centroid
            c = tri[~ok].mean(axis=1)
            t[~ok] = np.einsum("ij,ij->i", c - o[~ok], d[~ok])
            u[~ok] = v[~ok] = 1 / 3
        u = np.clip(u, 0.0, 1.0)
        v = np.clip(v, 0.0, 1.0)
        over = u + v > 1.0
        tot = (u + v)[over]
        u[over] /= tot
        v[over] /= tot
        return t, np.stack([u, v], axis=1)

    def alpha(self, faces: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Coverage alpha at hits: base colour × texture (bilinear, repeat) × vertex colour.

        Parameters
        ----------
        faces : ndarray, shape (M,)
        bary : ndarray, shape (M, 2)

        Returns
        -------
        ndarray, shape (M,), float64
        """
        out = np.ones(len(faces))
        w = np.column_stack([1.0 - bary.sum(axis=1), bary])  # (M, 3)
        prim_ids = self.face_prim[faces]
        for pid in np.unique(prim_ids):
            sel = np.flatnonzero(prim_ids == pid)
            prim = self.scene.primitives[pid]
            mat = prim.material
            a = np.full(len(sel), float(mat.base_color[3]))
            idx = prim.indices[self.face_local[faces[sel]]].astype(np.int64)  # (S, 3)
            ws = w[sel]
            if mat.texture is not None and prim.uv is not None:
                uv = np.einsum("sk,skc->sc", ws, prim.uv[idx].astype(np.float64))
                uv = np.nan_to_num(uv, nan=0.0, posinf=0.0, neginf=0.0)
                a *= _texel_alpha(mat.texture, uv, mat.sampler)
            if prim.colors is not None:
                a *= np.einsum("sk,sk->s", ws, prim.colors[idx, 3].astype(np.float64))
            out[sel] = a
        return out

    def first_hits(
        self,
        bvh: _Bvh,
        origins: np.ndarray,
        dirs: np.ndarray,
        t_max: np.ndarray,
        test: np.ndarray,
        threshold: np.ndarray,
        eps: np.ndarray | None = None,
        start_face: np.ndarray | None = None,
        cull: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Nearest hit along each ray that passes the alpha test (and, with ``cull``, meets a
        front face), before ``t_max``.

        Parameters
        ----------
        origins, dirs : ndarray, shape (N, 3)
            Normalised frame; ``dirs`` are unit vectors.
        t_max : ndarray, shape (N,)
            Hits at or beyond this distance count as misses.
        test, threshold : ndarray, shape (F,)
            Per face: whether hits need an alpha test, and the alpha a hit needs to count.
        eps : ndarray, shape (N,), optional
            Per ray, the first step past a surface that does not count (default
            :data:`EPS_REL`); it doubles on a repeated hit.
        start_face : ndarray, shape (N,), optional
            The face each ray leaves, never counted as its hit.
        cull : ndarray, shape (F,), bool, optional
            Per face: whether a hit on its back (the ray along :attr:`front`) does not count,
            as the camera pass culls it.

        Returns
        -------
        face : ndarray, shape (N,), int64
            Global face index, -1 for no hit.
        t : ndarray, shape (N,)
            Distance from the origin, NaN for no hit.
        bary : ndarray, shape (N, 2)
        unresolved : ndarray, shape (N,), bool
            Rays that passed through ``MAX_LAYERS`` cut-out surfaces without an answer.
        """
        n = len(origins)
        face = np.full(n, -1, np.int64)
        t_out = np.full(n, np.nan)
        bary = np.zeros((n, 2))
        unresolved = np.zeros(n, bool)
        t_start = np.zeros(n)
        last = (np.full(n, -1, np.int64) if start_face is None
                else np.asarray(start_face, np.int64).copy())
        base = np.full(n, self.eps) if eps is None else np.asarray(eps, np.float64)
        step = base.copy()
        active = np.arange(n)
        for _ in range(MAX_LAYERS):
            if len(active) == 0:
                break
            o = origins[active] + dirs[active] * t_start[active, None]
            f = bvh.first(o, dirs[active])
            hit = f >= 0
            active, f, o = active[hit], f[hit], o[hit]
            if len(active) == 0:
                break
            tl, bc = self.intersect(f, o, dirs[active])
            tt = t_start[active] + np.maximum(tl, 0.0)
            near = tt < t_max[active]
            active, f, tt, bc = active[near], f[near], tt[near], bc[near]
            # A ray stepping off a surface cannot meet the same plane again: a repeat is float32
            # noise and is stepped over with a growing stride.
            stuck = f == last[active]
            counts = ~stuck
            if cull is not None:
                back = cull[f] & (np.einsum("ij,ij->i", self.front[f], dirs[active]) > 0)
                counts &= ~back
            check = counts & test[f]
            if check.any():
                counts[check] = self.alpha(f[check], bc[check]) >= threshold[f[check]]
            done = active[counts]
            face[done], t_out[done], bary[done] = f[counts], tt[counts], bc[counts]
            skip = ~counts
            rays = active[skip]
            step[rays] = np.where(stuck[skip], step[rays] * 2.0, base[rays])
            t_start[rays] = np.maximum(tt[skip], t_start[rays]) + step[rays]
            last[rays] = f[skip]
            active = rays
        else:
            unresolved[active] = True
        return face, t_out, bary, unresolved


def trace_reference(scene: Scene, camera: Camera, lights: list[Light]) -> ReferenceResult:
    """Ray-trace hard-shadow visibility of every pixel for every light.

    Parameters
    ----------
    scene : Scene
    camera : Camera
        Primary rays go through pixel centres and start at the near plane; surfaces beyond the far
        plane count as no geometry, as in the rasteriser.
    lights : list of Light

    Returns
    -------
    ReferenceResult

    Raises
    ------
    ReferenceUnavailable
        embreex is not installed.
    RequestError
        A light with a non-finite position or direction, or a zero-length direction.
    """
    t0 = time.perf_counter()
    for k, light in enumerate(lights):
        if not (np.all(np.isfinite(light.position)) and np.all(np.isfinite(light.direction))):
            raise RequestError(f"light {k} has a non-finite position or direction")
        if light.type != "point" and not np.linalg.norm(light.direction) > 0:
            raise RequestError(f"light {k} has a zero-length direction")
    # Centred where the renderer's view is (camera.view_origin): a close view of a part of a
    # vast scene, far from its centre, is traced in a frame beside the eye, where float32 keeps
    # the precision its pixels need.
    lo, hi = scene.bounds
    tr = _Tracer(scene, view_origin(camera, scene, (lo + hi) / 2).origin)
    h, w = camera.height, camera.width
    cam_o, dirs = camera.pixel_rays()
    forward = -camera.pose[:3, 2]
    cos_f = dirs @ forward  # > 0 for every pixel (1 for an orthographic camera)
    # Near/far planes are planes of constant depth: along each ray they sit at z / cos.
    t_near = camera.znear / cos_f / tr.diag
    t_far = camera.zfar / cos_f / tr.diag
    origins = (cam_o - tr.centre) / tr.diag + dirs * t_near[:, None]
    # Rays lost among more than MAX_LAYERS cut-outs come back as misses: no geometry, not valid.
    face, t, _, _ = tr.first_hits(
        tr.primary_bvh, origins, dirs, t_far - t_near, tr.primary_test, tr.primary_threshold,
        cull=tr.cull_back,
    )
    hit = face >= 0
    depth = np.full(h * w, np.nan)
    depth[hit] = (t[hit] + t_near[hit]) * tr.diag * cos_f[hit]

    pix = np.flatnonzero(hit)
    f = face[pix]
    d = dirs[pix]
    p = origins[pix] + d * t[pix, None]  # normalised frame
    # Shadow-ray offsets from the local geometry (module docstring): float32 steps of each
    # surface triangle's coordinates, or a fraction of the pixel's footprint (normalised frame).
    if camera.orthographic:  # the same at every distance
        footprint = np.full(len(pix), float(camera.pixel_size(1.0)) / tr.diag)
    else:
        footprint = (t[pix] + t_near[pix]) * (2 * np.tan(camera.yfov / 2) / h)
    eps_local = np.maximum(EPS_ULPS * 2.0**-24 * np.abs(tr.tri[f]).max(axis=(1, 2)),
                           EPS_PIXEL * footprint)
    eps_local = np.maximum(eps_local, 1e-12)
    n = tr.normal[f]
    # Geometric normal turned toward the camera: the side of the surface the pixel shows.
    n_cam = np.where((np.einsum("ij,ij->i", n, d) > 0)[:, None], -n, n)
    receives = tr.receive_inst[tr.face_inst[f]]

    n_lights = len(lights)
    vis = np.full((h * w, n_lights), np.nan, np.float32)
    valid = np.zeros((h * w, n_lights), bool)
    for k, light in enumerate(lights):
        if light.type == "directional":
            ld = -np.asarray(light.direction, np.float64)
            to_l = np.broadcast_to(ld / np.linalg.norm(ld), p.shape)
            dist = np.full(len(p), np.inf)
        else:
            lp = (np.asarray(light.position, np.float64) - tr.centre) / tr.diag
            delta = lp - p
            dist = np.linalg.norm(delta, axis=1)
            to_l = np.divide(delta, dist[:, None], out=np.zeros_like(delta),
                             where=dist[:, None] > 0)
        cos_l = np.einsum("ij,ij->i", n_cam, to_l)
        ok = (cos_l > FACING_COS) & receives
        if light.type == "spot":
            axis = np.asarray(light.direction, np.float64)
            axis = axis / np.linalg.norm(axis)
            ok &= -(to_l @ axis) > np.cos(light.outer_cone)
        if light.type != "directional" and light.range is not None:
            ok &= dist * tr.diag <= light.range

        lit = np.ones(len(p), np.float32)
        # No shadow ray from a surface the light sits on (no direction) or from a degenerate
        # triangle (no normal to offset along): those pixels count as lit.
        trace = (dist > 2 * eps_local) & np.any(n != 0, axis=1)
        if not light.cast_shadows:
            trace[:] = False
        if trace.any():
            ti = np.flatnonzero(trace)
            nl = n_cam[ti]
            nl = np.where((np.einsum("ij,ij->i", nl, to_l[ti]) < 0)[:, None], -nl, nl)
            eps = eps_local[ti, None]
            so = p[ti] + nl * eps + to_l[ti] * eps
            if light.type == "directional":
                sd = np.ascontiguousarray(to_l[ti])
                smax = np.full(len(ti), np.inf)
            else:
                sdelta = lp - so
                sdist = np.linalg.norm(sdelta, axis=1)
                sd = sdelta / sdist[:, None]
                # The light is a point, not a surface: stop just short of it (float64 exact
                # intersection), so casters very close to the light still count.
                smax = sdist * (1.0 - 1e-9)
            sface, _, _, sun = tr.first_hits(
                tr.shadow_bvh, so, sd, smax, tr.shadow_test, tr.shadow_threshold,
                eps=eps[:, 0], start_face=f[ti],
            )
            lit[ti] = (sface < 0).astype(np.float32)
            ok[ti[sun]] = False
        vis[pix, k] = lit
        valid[pix, k] = ok

    return ReferenceResult(
        visibility=vis.reshape(h, w, n_lights),
        valid=valid.reshape(h, w, n_lights),
        depth=depth.astype(np.float32).reshape(h, w),
        seconds=time.perf_counter() - t0,
    )
