"""The renderer's own scene description, and loading glTF scenes into it.

:func:`load_scene` reads glTF 2.0 with the project's numpy reader (:mod:`shadowmap.renderer.gltf`:
container, accessors, nodes, skins, morph targets, materials, extensions) and flattens it into
plain numpy arrays that the GL passes, the planner and the ray-traced reference all share.
Everything the reader drops or approximates is listed in :attr:`Scene.warnings`.
:func:`scene_from_meshes` builds a scene from trimesh meshes (tests, demo scenes).

The loader never opens a path named inside a file and never fetches a URL: external buffers and
images are looked up in a mapping the caller provides, and anything that is not a plain relative
name (``../``, absolute paths, ``file:``, ``http:``) is refused.
"""

from __future__ import annotations

import dataclasses
import json
import os
import posixpath
import stat
import threading
import weakref
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from operator import attrgetter
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar
from urllib.parse import unquote

import numpy as np

from .cache import content_key
from .errors import LimitError, SceneError, ShadowMapError
from .limits import Limits, check_scene

if TYPE_CHECKING:
    import trimesh


#: A blended surface casts a shadow where its alpha reaches this (a cut-out at half coverage):
#: a shadow map holds one depth per texel, so it cannot cast a partial shadow.
BLEND_SHADOW_CUTOFF = 0.5
#: Gap between the added ground plane and the scene's lowest point, as a share of the scene's
#: diagonal. Objects resting on the ground leave a crevice of this height under their edges;
#: no shadow map resolves it (it is far below a texel), so the ground seen in it is drawn lit
#: where the truth is in shadow. Small enough that a camera almost never sees into it, large
#: enough to stay at least 16 float32 steps in the plane's own coordinates (stored relative to the
#: scene's centre) and in the reference's normalised frame, so the plane never ties with a
#: bottom face.
GROUND_GAP = 1e-6
#: The largest float32, the type of positions in glTF and on the GPU.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _read_only(*arrays: np.ndarray | None) -> None:
    """Make a scene's arrays read-only: a renderer keeps what it read of a scene (its GPU
    upload, its instance arrays, its plans) for as long as the scene lives, so a change in place
    would go unseen and draw the old content. Writing to one raises ``ValueError`` instead;
    changed content is a new :class:`Scene`."""
    for a in arrays:
        if isinstance(a, np.ndarray):
            a.flags.writeable = False


#: glTF's sampler values, which are OpenGL's enums.
NEAREST, LINEAR = 9728, 9729
NEAREST_MIPMAP_NEAREST, LINEAR_MIPMAP_NEAREST = 9984, 9985
NEAREST_MIPMAP_LINEAR, LINEAR_MIPMAP_LINEAR = 9986, 9987
REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648
MAG_FILTERS = {NEAREST: "NEAREST", LINEAR: "LINEAR"}
MIN_FILTERS = {**MAG_FILTERS, NEAREST_MIPMAP_NEAREST: "NEAREST_MIPMAP_NEAREST",
               LINEAR_MIPMAP_NEAREST: "LINEAR_MIPMAP_NEAREST",
               NEAREST_MIPMAP_LINEAR: "NEAREST_MIPMAP_LINEAR",
               LINEAR_MIPMAP_LINEAR: "LINEAR_MIPMAP_LINEAR"}
WRAPS = {REPEAT: "REPEAT", CLAMP_TO_EDGE: "CLAMP_TO_EDGE", MIRRORED_REPEAT: "MIRRORED_REPEAT"}


@dataclass(frozen=True)
class Sampler:
    """How a texture is filtered and wrapped: a glTF sampler, whose values are OpenGL's enums.

    The defaults are glTF's for wrapping (``REPEAT``) and this renderer's choice where glTF
    leaves the filters to the implementation (bilinear, trilinear between mipmaps).

    Attributes
    ----------
    mag_filter : int
        ``NEAREST`` or ``LINEAR``: the filter where a texel covers more than a pixel, and of the
        alpha cut-out tests, which read level 0 in both passes.
    min_filter : int
        One of :data:`MIN_FILTERS`: the filter where a pixel covers more than a texel.
    wrap_s, wrap_t : int
        ``REPEAT``, ``CLAMP_TO_EDGE`` or ``MIRRORED_REPEAT``, along u and v.
    """

    mag_filter: int = LINEAR
    min_filter: int = LINEAR_MIPMAP_LINEAR
    wrap_s: int = REPEAT
    wrap_t: int = REPEAT

    def __post_init__(self) -> None:
        for name, value, allowed in (("mag_filter", self.mag_filter, MAG_FILTERS),
                                     ("min_filter", self.min_filter, MIN_FILTERS),
                                     ("wrap_s", self.wrap_s, WRAPS),
                                     ("wrap_t", self.wrap_t, WRAPS)):
            if isinstance(value, bool) or not isinstance(value, int) or value not in allowed:
                raise SceneError(f"sampler {name} {value!r} is not one of "
                                 f"{', '.join(f'{k} ({v})' for k, v in allowed.items())}")

    @property
    def mipmapped(self) -> bool:
        """Whether the minification filter reads mipmaps."""
        return self.min_filter >= NEAREST_MIPMAP_NEAREST

    @property
    def periodic(self) -> tuple[bool, bool]:
        """Per axis (u, v), whether the texture repeats (or mirrors) with a period of 2: moving
        that coordinate by an even number samples the same texel."""
        return self.wrap_s != CLAMP_TO_EDGE, self.wrap_t != CLAMP_TO_EDGE


@dataclass(frozen=True, eq=False)
class Material:
    """The parts of a glTF metallic-roughness material this renderer honours.

    Attributes
    ----------
    base_color : ndarray, shape (4,), float32
        ``baseColorFactor`` (linear RGBA).
    texture : ndarray or None, shape (H, W, 4), uint8
        ``baseColorTexture`` (sRGB RGB, linear alpha), rows top to bottom as in the image file.
    alpha_mode : {"OPAQUE", "MASK", "BLEND"}
    alpha_cutoff : float
        Used when ``alpha_mode == "MASK"``.
    double_sided : bool
    unlit : bool
        ``KHR_materials_unlit``: the colour image shows the base colour as it is (no lighting,
        no shadow); the surface still casts shadows and has visibility.
    sampler : Sampler
        How ``texture`` is filtered and wrapped.
    """

    base_color: np.ndarray
    texture: np.ndarray | None = None
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    double_sided: bool = False
    unlit: bool = False
    sampler: Sampler = Sampler()

    def __post_init__(self) -> None:
        _read_only(self.base_color, self.texture)

    @property
    def shadow_cutoff(self) -> float | None:
        """Alpha below which the surface casts no shadow: its cutoff for MASK,
        :data:`BLEND_SHADOW_CUTOFF` for BLEND, None (no test) for OPAQUE."""
        if self.alpha_mode == "MASK":
            return float(self.alpha_cutoff)
        if self.alpha_mode == "BLEND":
            return BLEND_SHADOW_CUTOFF
        return None

    @property
    def shadow_texture_cut(self) -> bool:
        """Whether its shadow is cut out by its texture's alpha: the light pass alpha-tests it
        against the texture (a cutoff and a texture), so a face may have holes."""
        return self.shadow_cutoff is not None and self.texture is not None


@dataclass(frozen=True, eq=False)
class Primitive:
    """One triangle mesh in its local frame (a glTF mesh primitive).

    Frozen, its arrays read-only (:func:`_read_only`): a renderer keeps what it read of a scene,
    so changed content is a new primitive in a new :class:`Scene` (``dataclasses.replace``).

    Attributes
    ----------
    positions : ndarray, shape (N, 3), float32
    normals : ndarray, shape (N, 3), float32
        Unit vertex normals (computed when the file has none).
    indices : ndarray, shape (F, 3), uint32
    material : Material
    uv : ndarray or None, shape (N, 2), float32
        The base-colour texture's ``TEXCOORD_n`` (after ``KHR_texture_transform``) in OpenGL's
        convention, as trimesh gives it: v = 1 - glTF v, so v = 0 is the bottom row of the
        image. Present only when the material has a texture.
    colors : ndarray or None, shape (N, 4), float32
        ``COLOR_0`` (linear RGBA), present only when the file has vertex colours.
    """

    positions: np.ndarray
    normals: np.ndarray
    indices: np.ndarray
    material: Material
    uv: np.ndarray | None = None
    colors: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        _read_only(self.positions, self.normals, self.indices, self.uv, self.colors)

    @property
    def local_bounds(self) -> np.ndarray:
        """ndarray, shape (2, 3): axis-aligned min and max corner in the local frame."""
        return np.stack([self.positions.min(axis=0), self.positions.max(axis=0)])


@dataclass(eq=False)
class Instance:
    """A primitive placed in the world by a node.

    A scene's loaders and builders make its instances' arrays read-only (rows of one read-only
    array, made once for all of them), as :class:`Primitive`'s are. An instance is not frozen,
    as a file may hold 100,000 and a frozen dataclass costs more to make, but changing one in a
    scene a renderer has read is not seen (:func:`instance_arrays`): build a new
    :class:`Scene`.

    Attributes
    ----------
    primitive : int
        Index into :attr:`Scene.primitives`.
    matrix : ndarray, shape (4, 4), float64
        Local-to-world transform.
    cast_shadow, receive_shadow : bool
        From ``extras.castShadow`` / ``extras.receiveShadow`` on the node or its mesh (default
        true).
    bounds : ndarray, shape (2, 3), float64
        World-space axis-aligned bounds.
    """

    primitive: int
    matrix: np.ndarray
    cast_shadow: bool = True
    receive_shadow: bool = True
    name: str = ""
    bounds: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))


@dataclass(frozen=True)
class SceneCamera:
    """A camera found in the file: ``pose`` is camera-to-world (4, 4).

    A perspective camera has ``yfov`` (radians) and ``ymag`` None; an orthographic one has
    ``ymag`` (half the view's height, scene units) and ``yfov`` None.
    """

    pose: np.ndarray
    yfov: float | None
    znear: float | None
    zfar: float | None
    aspect: float | None = None
    ymag: float | None = None


@dataclass(frozen=True)
class SceneLight:
    """A ``KHR_lights_punctual`` light: ``pose`` is light-to-world (4, 4), looking down −Z."""

    type: str
    pose: np.ndarray
    color: tuple[float, float, float]
    intensity: float
    range: float | None
    inner_cone: float
    outer_cone: float


@dataclass(eq=False)
class Scene:
    """A loaded scene: flat lists of primitives and their world instances.

    Attributes
    ----------
    primitives : list of Primitive
    instances : list of Instance
    cameras : list of SceneCamera
    lights : list of SceneLight
    key : str
        SHA-256 of the file and its resources, for caching.
    warnings : list of str
        What the loader dropped or approximated (a left-out primitive, a texture that could not
        be decoded, an ignored optional extension, ...), each once.
    """

    primitives: list[Primitive]
    instances: list[Instance]
    cameras: list[SceneCamera] = field(default_factory=list)
    lights: list[SceneLight] = field(default_factory=list)
    key: str = ""
    #: Bounds the automatic camera frames, when not all of :attr:`bounds` (e.g. an added ground).
    focus: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def bounds(self) -> np.ndarray:
        """ndarray, shape (2, 3): world-space bounds of every instance (a new array each call).

        Read from :func:`instance_arrays`, so once per scene: see there for when changes to the
        scene are seen.
        """
        return instance_arrays(self).box.copy()

    @property
    def triangle_count(self) -> int:
        """Triangles drawn per pass, counting every instance.

        The instances' primitive indices come from :func:`instance_arrays`; each primitive's
        triangle count is read on every call.
        """
        counts = instance_arrays(self).instances_per_primitive(len(self.primitives))
        return int(sum(int(c) * len(p.indices)
                       for c, p in zip(counts.tolist(), self.primitives, strict=True) if c))

    def with_ground(self, color: Sequence[float] = (0.8, 0.8, 0.8, 1.0)) -> Scene:
        """This scene plus a ground plane under it (receives shadows, casts none).

        The plane lies :data:`GROUND_GAP` of the scene's diagonal below its lowest point (along
        +Y, glTF's up) and extends three times the scene's footprint in every direction.
        """
        lo, hi = self.bounds
        c = (lo + hi) / 2
        r = max(float(np.max(hi - lo)), 1e-30) * 3
        y = lo[1] - float(np.linalg.norm(hi - lo)) * GROUND_GAP
        pos = np.array([[-r, 0, -r], [r, 0, -r], [r, 0, r], [-r, 0, r]], np.float64)
        pos[:, [0, 2]] += c[[0, 2]]
        pos[:, 1] = y
        ground = Primitive(
            positions=(pos - c).astype(np.float32),
            normals=np.tile(np.array([0, 1, 0], np.float32), (4, 1)),
            indices=np.array([[0, 2, 1], [0, 3, 2]], np.uint32),
            material=Material(np.asarray(color, np.float32), double_sided=True),
            name="ground",
        )
        m = np.eye(4)
        m[:3, 3] = c
        bounds = np.stack([pos.min(axis=0), pos.max(axis=0)])
        _read_only(m, bounds)
        inst = Instance(len(self.primitives), m, cast_shadow=False, receive_shadow=True,
                        name="ground", bounds=bounds)
        grounded = Scene(self.primitives + [ground], self.instances + [inst], self.cameras,
                         self.lights, key=self.key + ":ground" if self.key else "",
                         focus=np.stack([lo, hi]) if self.focus is None else self.focus,
                         warnings=list(self.warnings))
        # The new scene's arrays are this scene's plus one row: never read 50,000 instances again.
        _extend_arrays(self, grounded)
        return grounded

    def world_triangles(self, instance: Instance,
                        origin: np.ndarray | None = None) -> np.ndarray:
        """Triangles of one instance in world space, or relative to ``origin``.

        Parameters
        ----------
        instance : Instance
        origin : ndarray, shape (3,), optional
            Subtracted from the instance's translation before its vertices are placed: a part
            far smaller than its distance from the world's origin keeps the precision float64
            has beside ``origin`` (world coordinates of a part 1e-6 across, 1.8e8 units out,
            step by 3e-8, 4 % of its size).

        Returns
        -------
        ndarray, shape (F, 3, 3), float64
        """
        prim = self.primitives[instance.primitive]
        move = instance.matrix[:3, 3]
        if origin is not None:
            move = move - np.asarray(origin, np.float64)
        v = prim.positions.astype(np.float64) @ instance.matrix[:3, :3].T + move
        return v[prim.indices]


# --------------------------------------------------------------------------------------------
# A scene's instances as arrays
# --------------------------------------------------------------------------------------------

# InstanceArrays by scene, weakly: nothing is written into the scene, and the entry goes with it.
_ARRAYS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_ARRAYS_LOCK = threading.Lock()


def _stacked(name: str, shape: tuple[int, ...]) -> Callable[[list[Instance]], np.ndarray]:
    """Reads one array attribute of every instance into one float64 array (n, *shape)."""
    get = attrgetter(name)

    def read(insts: list[Instance]) -> np.ndarray:
        if not insts:
            return np.zeros((0, *shape))
        # Concatenating along the first axis copies the same values as np.stack, at half the
        # cost; the map keeps the per-instance work inside C loops.
        flat = np.concatenate(list(map(get, insts)))
        return flat.astype(np.float64, copy=False).reshape(len(insts), *shape)

    return read


def _flags(name: str, dtype: type) -> Callable[[list[Instance]], np.ndarray]:
    get = attrgetter(name)
    return lambda insts: np.fromiter(map(get, insts), dtype, len(insts))


class InstanceArrays:
    """What the renderer reads of a scene's instances, as read-only arrays over all of them.

    Each array is read out of the :class:`Instance` objects the first time it is asked for,
    then kept (:func:`instance_arrays` keeps one object per scene). A scene made by
    :meth:`Scene.with_ground` starts from its source's arrays plus one row.

    Attributes
    ----------
    primitive : ndarray, shape (N,), intp
        Each instance's index into :attr:`Scene.primitives`.
    matrices : ndarray, shape (N, 4, 4), float64
        Local-to-world matrices.
    bounds : ndarray, shape (N, 2, 3), float64
        World boxes, as in :attr:`Instance.bounds`.
    receive : ndarray, shape (N,), bool
        ``receive_shadow``.
    box : ndarray, shape (2, 3)
        The box around every instance (:attr:`Scene.bounds`).
    """

    _readers: ClassVar[dict[str, Callable[[list[Instance]], np.ndarray]]] = {
        "primitive": _flags("primitive", np.intp),
        "matrices": _stacked("matrix", (4, 4)),
        "bounds": _stacked("bounds", (2, 3)),
        "receive": _flags("receive_shadow", bool),
    }

    def __init__(self, scene: Scene, base: InstanceArrays | None = None) -> None:
        self._source = _source(scene)
        self._instances = scene.instances
        # The arrays of the first len(base) instances (with_ground's source): only the rest
        # are read.
        self._base = base

    def __len__(self) -> int:
        return self._source[1]

    def _read(self, name: str) -> np.ndarray:
        read = self._readers[name]
        # Only the instances the entry was made for (a list grown since is a new entry's).
        insts = self._instances
        if self._base is None:
            out = read(insts if len(insts) == len(self) else insts[:len(self)])
        else:
            done = len(self._base)
            out = np.concatenate([getattr(self._base, name), read(insts[done:len(self)])])
        out.flags.writeable = False
        return out

    # cached_property is not thread-safe on every Python: a race reads the same values twice.
    @cached_property
    def primitive(self) -> np.ndarray:
        return self._read("primitive")

    @cached_property
    def matrices(self) -> np.ndarray:
        return self._read("matrices")

    @cached_property
    def bounds(self) -> np.ndarray:
        return self._read("bounds")

    @cached_property
    def receive(self) -> np.ndarray:
        return self._read("receive")

    @cached_property
    def box(self) -> np.ndarray:
        b = self.bounds
        if not len(b):
            raise ValueError("the scene has no instances: it has no bounds")
        box = np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])
        box.flags.writeable = False
        return box

    def instances_per_primitive(self, n_primitives: int) -> np.ndarray:
        """Number of instances of each primitive, shape (n_primitives,).

        Raises
        ------
        IndexError
            An instance names a primitive outside ``range(n_primitives)``.
        """
        prim = self.primitive
        if prim.size and (int(prim.min()) < 0 or int(prim.max()) >= n_primitives):
            raise IndexError("an instance refers to a primitive the scene does not have")
        return np.bincount(prim, minlength=n_primitives)


def _source(scene: Scene) -> tuple:
    """What a cached entry must still match: the scene's lists, by identity, and their lengths."""
    return (scene.instances, len(scene.instances), scene.primitives, len(scene.primitives))


def _same_source(a: tuple, b: tuple) -> bool:
    return a[0] is b[0] and a[1] == b[1] and a[2] is b[2] and a[3] == b[3]


def instance_arrays(scene: Scene) -> InstanceArrays:
    """The scene's instance arrays, read once per scene.

    An entry is reused while the scene holds the same ``instances`` and ``primitives`` lists
    with the same lengths (as the plan's per-scene arrays in :mod:`.plan.instances`): replacing
    either list, or appending to it, is seen; changing an :class:`Instance` in place (its matrix,
    bounds or flags) after the scene was read is not. Build a new :class:`Scene` for changed
    content (the upload cache keeps a scene's matrices on the GPU by its key anyway).
    """
    with _ARRAYS_LOCK:
        hit = _ARRAYS.get(scene)
    if hit is not None and _same_source(hit._source, _source(scene)):
        return hit
    arrays = InstanceArrays(scene)
    with _ARRAYS_LOCK:
        _ARRAYS[scene] = arrays
    return arrays


def preset_instance_arrays(scene: Scene, arrays: Mapping[str, np.ndarray]) -> None:
    """Give a new scene the instance arrays its loader built anyway (names as the attributes of
    :class:`InstanceArrays`), so that they are not read back out of its :class:`Instance`
    objects. Arrays not given are read as usual; each given one must match the instances.
    """
    entry = InstanceArrays(scene)
    for name, a in arrays.items():
        if name not in InstanceArrays._readers or len(a) != len(scene.instances):
            raise ValueError(f"not an instance array of this scene: {name!r}")
        a.flags.writeable = False
        entry.__dict__[name] = a  # what the cached_property would have computed
    with _ARRAYS_LOCK:
        _ARRAYS[scene] = entry


def _extend_arrays(source: Scene, grounded: Scene) -> None:
    """Give ``grounded`` (``source`` plus instances at the end) arrays built on the source's."""
    arrays = InstanceArrays(grounded, instance_arrays(source))
    with _ARRAYS_LOCK:
        _ARRAYS[grounded] = arrays


# --------------------------------------------------------------------------------------------
# Resolving external files safely
# --------------------------------------------------------------------------------------------


def safe_uri(uri: str, what: str = "") -> str:
    """The relative name a URI stands for inside the upload; SceneError for anything that could
    leave it.

    The one check of every external name: buffer and image URIs (at admission, in
    :func:`~shadowmap.renderer.gltf.reader.load_uri` and in :class:`MappingResolver`) and the
    resolver's own keys. ``data:`` URIs are not names: the reader decodes them before asking.

    Parameters
    ----------
    uri : str
        As written in the file (percent-escapes and backslashes allowed).
    what : str, optional
        Who refers to it (``"buffer 0"``, ``"image 2"``), for the message.

    Raises
    ------
    SceneError
        A scheme (``file:``, ``http:``, a drive letter), an absolute path, ``..`` above the
        upload's root, an empty name or a NUL.
    """
    who = f"{what}: " if what else ""
    if not isinstance(uri, str):
        raise SceneError(f"{who}the URI {uri!r} is not a string")
    name = unquote(uri).replace("\\", "/")
    if ":" in name.split("/", 1)[0] or name.startswith("/") or "\0" in name:
        raise SceneError(f"{who}refusing URI {uri!r}: only relative names inside the upload "
                         "are allowed")
    norm = posixpath.normpath(name)
    if norm == ".." or norm.startswith("../") or norm.startswith("/") or norm in ("", "."):
        raise SceneError(f"{who}refusing URI {uri!r}: it points outside the upload")
    return norm


class MappingResolver:
    """External files from a mapping of relative name -> bytes; refuses unsafe names.

    The glTF reader's resolver (``get``); ``namespaced`` and ``write`` complete trimesh's
    resolver interface.
    """

    def __init__(self, resources: Mapping[str, bytes] | None) -> None:
        self._files = {safe_uri(k): v for k, v in (resources or {}).items()}
        # Where the files were read from, when from a folder (FolderResources): a missing one
        # is then said to be missing there, not "not provided".
        self._folder = getattr(resources, "folder", None)

    def get(self, name: str) -> bytes:
        key = safe_uri(name)
        if key not in self._files:
            where = (f"which is not in {self._folder}" if self._folder is not None
                     else "which was not provided")
            raise SceneError(f"the file refers to {name!r}, {where}")
        return self._files[key]

    __getitem__ = get

    def namespaced(self, namespace: str) -> MappingResolver:
        sub = MappingResolver(None)
        prefix = safe_uri(namespace) + "/"
        sub._files = {k[len(prefix):]: v for k, v in self._files.items() if k.startswith(prefix)}
        return sub

    def write(self, name: str, data: bytes) -> None:  # trimesh's interface; loading never writes
        raise SceneError("the resolver is read-only")


class FolderResources(dict[str, bytes]):
    """The files a ``.gltf`` names, as read from its folder (:func:`gltf_resources`): a mapping
    of relative name -> bytes that remembers the folder, for messages."""

    def __init__(self, folder: Path) -> None:
        super().__init__()
        self.folder = folder


def read_regular_file(path: str | Path, what: str, max_bytes: int | None = None) -> bytes:
    """The content of the regular file at ``path``, at most ``max_bytes`` of it.

    The file is opened without waiting and checked before anything is read: a FIFO would block
    the read until something writes to it (forever, in a batch), and a device such as
    ``/dev/zero`` or ``/dev/urandom`` would never end it, filling memory. Symbolic links are
    followed to what they name, which must be a regular file too.

    Parameters
    ----------
    path : path
    what : str
        How errors name the file, e.g. ``"buffer 0 (scene.bin)"``.
    max_bytes : int, optional
        Most bytes read: a larger file (or one that grows past it while read) raises
        :class:`LimitError` (``max_request_bytes``).

    Raises
    ------
    OSError
        It cannot be opened or read, or is a folder (the caller says what it was for).
    SceneError
        It is a FIFO, a device or a socket.
    LimitError
        It holds more than ``max_bytes``.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    with open(fd, "rb", buffering=0, closefd=True) as f:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            # (A folder never gets here: opening it for reading is IsADirectoryError.)
            kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a socket"
                    if stat.S_ISSOCK(st.st_mode) else "a device")
            raise SceneError(f"{what} is {kind}, not a regular file")
        if max_bytes is not None and st.st_size > max_bytes:
            raise LimitError("max_request_bytes", f"{what} holds {st.st_size} bytes, over the "
                             f"{max_bytes} this request may read")
        os.set_blocking(fd, True)
        data = f.read() if max_bytes is None else f.read(max_bytes + 1)
    if max_bytes is not None and len(data) > max_bytes:
        raise LimitError("max_request_bytes", f"{what} grew past {max_bytes} bytes while read")
    return data


def gltf_resources(path: str | Path, data: bytes,
                   max_bytes: int | None = None) -> FolderResources:
    """The external files a ``.gltf`` names (buffers and images, not ``data:`` URIs), read from
    its folder: the one way a scene file on disk gets its resources (library, CLI and batch).

    Only what the file refers to is read (a folder of many models is not read whole), and every
    name goes through :func:`safe_uri`, so nothing outside the folder is opened. A named file
    that does not exist is left out: the loader then refuses a missing buffer
    (:class:`SceneError`) and drops a missing image with a warning, as it does for an upload.

    Parameters
    ----------
    path : path
        The ``.gltf`` file (its folder is the root of every relative URI).
    data : bytes
        Its content, already read. Not JSON (a GLB): no resources.
    max_bytes : int, optional
        Most bytes read in all; a file that would go past it raises :class:`LimitError`
        (``max_request_bytes``) before it is read.

    Returns
    -------
    FolderResources
        Relative name -> bytes, with the folder (a missing file is then said to be missing
        there).

    Raises
    ------
    SceneError
        A URI that could leave the folder; a named file that exists but cannot be read.
    LimitError
        The files named add up to more than ``max_bytes``.
    """
    path = Path(path)
    root = path.parent
    out = FolderResources(root)
    if data[:4] == b"glTF":
        return out
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        return out  # the loader gives the proper error
    if not isinstance(doc, dict):
        return out
    total = 0
    for kind in ("buffers", "images"):
        items = doc.get(kind)
        for i, item in enumerate(items if isinstance(items, list) else []):
            uri = item.get("uri") if isinstance(item, dict) else None
            if not isinstance(uri, str) or uri[:5].lower() == "data:":
                continue
            name = safe_uri(uri, f"{kind[:-1]} {i}")
            if name in out:
                continue
            file = root / name
            left = None if max_bytes is None else max_bytes - total
            what = f"{kind[:-1]} {i} ({name} beside {path.name})"
            try:
                out[name] = read_regular_file(file, what, left)
            except FileNotFoundError:
                continue
            except OSError as exc:
                raise SceneError(f"{kind[:-1]} {i}: cannot read {name} beside {path.name}: "
                                 f"{exc.strerror}") from None
            except LimitError:
                raise LimitError("max_request_bytes",
                                 f"the files {path.name} names exceed {max_bytes} bytes "
                                 f"(at {kind[:-1]} {i}, {name})") from None
            total += len(out[name])
    return out


# --------------------------------------------------------------------------------------------
# Scenes from trimesh meshes
# --------------------------------------------------------------------------------------------


def _flag(meta: dict | None, key: str) -> bool | None:
    if isinstance(meta, dict) and isinstance(meta.get(key), bool):
        return meta[key]
    return None


def _material(visual: Any) -> tuple[Material, np.ndarray | None, np.ndarray | None]:
    """Material, per-vertex uv (when textured) and per-vertex colours (when present)."""
    import trimesh

    uv = colors = None
    if isinstance(visual, trimesh.visual.ColorVisuals):
        vc = visual.vertex_colors if visual.kind == "vertex" else None
        if vc is not None:
            colors = np.asarray(vc, dtype=np.float32) / 255.0
        face_color = (
            np.asarray(visual.main_color, np.float32) / 255.0
            if visual.kind == "face"
            else np.ones(4, np.float32)
        )
        return Material(base_color=face_color), None, colors
    mat = getattr(visual, "material", None)
    factor = np.ones(4, np.float32)
    texture = None
    alpha_mode, cutoff, double_sided = "OPAQUE", 0.5, False
    if mat is not None:
        bcf = getattr(mat, "baseColorFactor", None)
        if bcf is not None:
            factor = np.asarray(bcf, np.float32) / 255.0
        img = getattr(mat, "baseColorTexture", None)
        if img is None and hasattr(mat, "image"):  # SimpleMaterial
            img = mat.image
        if img is not None and getattr(visual, "uv", None) is not None:
            texture = np.asarray(img.convert("RGBA"), dtype=np.uint8)
            uv = np.array(visual.uv, np.float32)  # a copy: a scene's arrays are made read-only
        alpha_mode = (getattr(mat, "alphaMode", None) or "OPAQUE").upper()
        cutoff = float(getattr(mat, "alphaCutoff", None) or 0.5)
        double_sided = bool(getattr(mat, "doubleSided", False))
    vc = (getattr(visual, "vertex_attributes", {}).get("color")
          if hasattr(visual, "vertex_attributes") else None)
    if vc is not None:
        colors = np.asarray(vc, np.float32)
        if colors.max(initial=0) > 1.0:
            colors = colors / 255.0
    return Material(factor, texture, alpha_mode, cutoff, double_sided), uv, colors


def _primitive_from_trimesh(mesh: trimesh.Trimesh, name: str) -> Primitive:
    faces = np.asarray(mesh.faces, dtype=np.int64)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise SceneError(f"mesh {name!r} has no triangles")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise SceneError(f"mesh {name!r} has indices outside its vertex array")
    if not np.all(np.isfinite(verts)):
        raise SceneError(f"mesh {name!r} has NaN or infinite vertex positions")
    # Positions are float32 on the GPU, as in glTF: past its range they would turn infinite.
    largest = float(np.abs(verts).max(initial=0.0))
    if largest > FLOAT32_MAX:
        raise SceneError(f"mesh {name!r} has vertex positions beyond float32's range "
                         f"({largest:.3g}; at most {FLOAT32_MAX:.3g})")
    material, uv, colors = _material(mesh.visual)
    if uv is not None and len(uv) != len(verts):
        uv, material = None, dataclasses.replace(material, texture=None)
    if colors is not None and len(colors) != len(verts):
        colors = None
    if colors is not None and np.allclose(colors, 1.0):
        colors = None  # all-white vertex colours change nothing: leave the path out
    normals = None
    if "vertex_normals" in mesh._cache:  # the file's NORMAL attribute, as trimesh loaded it
        normals = np.asarray(mesh.vertex_normals, np.float64)
        if normals.shape != verts.shape or not np.all(np.isfinite(normals)):
            normals = None
    if normals is None:
        normals = _vertex_normals(verts, faces)
    return Primitive(
        positions=verts.astype(np.float32),
        normals=normals.astype(np.float32),
        indices=faces.astype(np.uint32),
        material=material,
        uv=uv,
        colors=None if colors is None else colors.astype(np.float32),
        name=name,
    )


def _vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals.

    Zero-area triangles contribute nothing, lone vertices get +Y.
    """
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    length = np.linalg.norm(vn, axis=1, keepdims=True)
    bad = length[:, 0] <= 1e-300
    vn[~bad] /= length[~bad]
    vn[bad] = (0.0, 1.0, 0.0)
    return vn.astype(np.float32)


def world_bounds_many(local: np.ndarray, mats: np.ndarray) -> np.ndarray:
    """World bounds of a local box under many matrices at once.

    Parameters
    ----------
    local : ndarray, shape (2, 3)
    mats : ndarray, shape (K, 4, 4)

    Returns
    -------
    ndarray, shape (K, 2, 3)
    """
    corners = np.array(np.meshgrid(*local.T, indexing="ij")).reshape(3, -1).T  # (8, 3)
    w = np.einsum("kij,cj->kci", mats[:, :3, :3], corners) + mats[:, None, :3, 3]
    return np.stack([w.min(axis=1), w.max(axis=1)], axis=1)


def world_bounds(local: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """World bounds (2, 3) of a local box (2, 3) under one matrix (4, 4)
    (:func:`world_bounds_many`)."""
    return world_bounds_many(local, matrix[None])[0]


def read_source(source: object, file_type: str | None, resources: Mapping[str, bytes] | None,
                max_bytes: int | None = None
                ) -> tuple[bytes, str | None, Mapping[str, bytes] | None]:
    """A scene file's bytes, its type hint and its external files, from what a caller gave.

    A path (``str`` or ``os.PathLike``) is read, its suffix is the type hint unless
    ``file_type`` is given, and a ``.gltf``'s files are read from beside it unless
    ``resources`` is given (:func:`gltf_resources`, within ``max_bytes``); anything else that
    holds bytes (``bytes``, ``bytearray``, ``memoryview``, an array) is the file itself.

    Raises
    ------
    SceneError
        The file cannot be read or is no regular file (:func:`read_regular_file`), or
        ``source`` is neither a path nor bytes (``None``, a number, a trimesh point cloud, ...).
    LimitError
        The file, or the files a ``.gltf`` names, hold more than ``max_bytes``.
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        try:
            data = read_regular_file(path, str(path), max_bytes)
        except OSError as exc:
            raise SceneError(f"cannot read {path}: {exc.strerror}") from None
        except ValueError as exc:  # a NUL in the path
            raise SceneError(f"cannot read {str(path)!r}: {exc}") from None
        if resources is None:
            resources = gltf_resources(path, data, max_bytes)
        return data, file_type or path.suffix, resources
    try:
        view = memoryview(source)  # type: ignore[arg-type]
    except TypeError:
        raise SceneError(f"cannot load a scene from a value of type {type(source).__name__}: "
                         "give a path, a .glb or .gltf file's bytes, a Scene, or a trimesh "
                         "Trimesh or Scene") from None
    return view.tobytes(), file_type, resources


def load_scene(
    source: str | Path | bytes,
    *,
    file_type: str | None = None,
    resources: Mapping[str, bytes] | None = None,
    limits: Limits | None = None,
    key: str | None = None,
) -> Scene:
    """Load a glTF 2.0 scene.

    Parameters
    ----------
    source : path or bytes
        A ``.glb`` or ``.gltf`` file. A ``.gltf`` given by its path reads the buffers and images
        it names from its folder (:func:`gltf_resources`) unless ``resources`` is given.
    file_type : str, optional
        ``"glb"``, ``"gltf"`` or a suffix: only a hint for messages. Binary or JSON is decided
        by the content (the magic ``glTF``), so a JSON glTF named ``.glb`` loads.
    resources : mapping of str to bytes, optional
        External buffers and images of a ``.gltf``, by the relative name used in the file.
    limits : Limits, optional
        Raise :class:`LimitError` when the scene breaks one: first from the JSON alone, before
        any data is decoded (:func:`~shadowmap.renderer.gltf.admission.admit`: nodes, depth,
        instances, primitives, declared triangles, decoded bytes), then
        :func:`~shadowmap.renderer.limits.check_scene` on the loaded scene. Without limits
        nothing is refused for its size (unsafe URIs still are).
    key : str, optional
        The content key of ``source`` and ``resources`` when the caller has computed it
        (:func:`~shadowmap.renderer.cache.content_key`).

    Returns
    -------
    Scene
        With :attr:`Scene.warnings` listing whatever was dropped or approximated.

    Raises
    ------
    UnsupportedExtension
        ``extensionsRequired`` names an extension the reader does not implement.
    SceneError
        Corrupt, truncated or unsupported file; unsafe or missing external URIs; no triangles.
    LimitError
        A limit of ``limits``.
    """
    from .gltf.loader import load_gltf
    from .gltf.reader import read_container

    data, file_type, resources = read_source(source, file_type, resources,
                                             limits.max_request_bytes if limits else None)
    try:
        document = read_container(data, file_type)
        resolver = MappingResolver(resources)
        loaded = load_gltf(document, resolver, limits)
    except ShadowMapError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, ArithmeticError,
            RecursionError) as exc:
        # The reader checks what it reads; this catches a malformed document it did not
        # anticipate, so bad input stays a SceneError (HTTP 400), never a crash. Nothing
        # recurses on the document today; should something, a deep one is still the file's.
        raise SceneError(f"malformed glTF ({type(exc).__name__}: {str(exc)[:200]})") from None
    except MemoryError:
        # The admission check bounds what a file may ask for; this is the backstop.
        raise LimitError("max_request_bytes", "loading the scene ran out of memory") from None
    scene = Scene(loaded.primitives, loaded.instances, loaded.cameras, loaded.lights,
                  key=key or content_key(data, resources), warnings=loaded.warnings)
    preset_instance_arrays(scene, loaded.arrays)
    if limits is not None:
        check_scene(scene, limits)
    return scene


def _check_trimesh_counts(obj: Any, limits: Limits) -> None:
    """:func:`scene_from_trimesh`'s counts, read from the scene graph alone."""
    nodes = obj.graph.nodes_geometry
    if len(nodes) > limits.max_instances:
        raise LimitError("max_instances", f"the trimesh scene has {len(nodes)} nodes drawing "
                         f"geometry, over the limit of {limits.max_instances}")
    if len(obj.geometry) > limits.max_primitives:
        raise LimitError("max_primitives", f"the trimesh scene has {len(obj.geometry)} "
                         f"geometries, over the limit of {limits.max_primitives}")
    faces = {name: len(getattr(g, "faces", ())) for name, g in obj.geometry.items()}
    triangles = sum(faces.get(str(obj.graph[node][1]), 0) for node in nodes)
    if triangles > limits.max_triangles:
        raise LimitError("max_triangles", f"the trimesh scene draws {triangles} triangles, over "
                         f"the limit of {limits.max_triangles}")


def is_trimesh(obj: object) -> bool:
    """Whether ``obj`` is a ``trimesh.Trimesh`` or ``trimesh.Scene`` (checked without importing
    trimesh where the caller has not)."""
    import sys

    tm = sys.modules.get("trimesh")
    return tm is not None and isinstance(obj, (tm.Trimesh, tm.Scene))


def scene_from_trimesh(obj: Any, limits: Limits | None = None) -> Scene:
    """A :class:`Scene` from a ``trimesh.Trimesh`` or ``trimesh.Scene``, what pyrender users hold.

    A ``Trimesh`` is one instance, its vertices taken as world space. A ``trimesh.Scene`` is read
    through its graph: every node that draws a geometry is an instance of it, with the node's
    world transform, and a geometry drawn by many nodes is one primitive (drawn instanced).
    ``castShadow`` / ``receiveShadow`` booleans are read from the geometry's ``metadata``, and
    from ``metadata["extras"]``, where trimesh keeps a glTF file's extras. Geometry that is not a
    triangle mesh (points, paths) is left out with a warning in :attr:`Scene.warnings`.

    With ``limits``, the counts are checked from the graph before any mesh is converted (the
    conversion is a loop over the meshes): nodes that draw a geometry against ``max_instances``,
    geometries against ``max_primitives``, triangles over every node against
    ``max_triangles``.

    Raises
    ------
    SceneError
        Nothing to draw; a mesh without triangles, with indices outside its vertices, or with
        non-finite vertices or transforms.
    LimitError
        Over one of ``limits``' counts.
    """
    import trimesh

    if isinstance(obj, trimesh.Trimesh):
        obj = trimesh.Scene(obj)
    if not isinstance(obj, trimesh.Scene):
        raise SceneError(f"not a trimesh mesh or scene: {type(obj).__name__}")
    if limits is not None:
        _check_trimesh_counts(obj, limits)
    primitives: list[Primitive] = []
    index: dict[str, int] = {}
    instances: list[Instance] = []
    warnings: list[str] = []
    flags: dict[str, tuple[bool, bool]] = {}
    for node in obj.graph.nodes_geometry:
        matrix, name = obj.graph[node]
        geom_name = str(name)
        geom = obj.geometry.get(geom_name)
        if not isinstance(geom, trimesh.Trimesh):
            warnings.append(f"node {node!r} draws {type(geom).__name__} {geom_name!r}, not a "
                            "triangle mesh: left out")
            continue
        m = np.array(matrix, np.float64)  # a copy: made read-only below, trimesh's is its own
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise SceneError(f"node {node!r} has a non-finite transform")
        if geom_name not in index:
            index[geom_name] = len(primitives)
            primitives.append(_primitive_from_trimesh(geom, geom_name))
            meta = geom.metadata if isinstance(geom.metadata, dict) else {}
            extras = meta.get("extras")
            cast = _flag(meta, "castShadow")
            receive = _flag(meta, "receiveShadow")
            cast = _flag(extras, "castShadow") if cast is None else cast
            receive = _flag(extras, "receiveShadow") if receive is None else receive
            flags[geom_name] = (cast is not False, receive is not False)
        p = index[geom_name]
        lo, hi = primitives[p].local_bounds.astype(np.float64)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        world = corners @ m[:3, :3].T + m[:3, 3]
        cast, receive = flags[geom_name]
        bounds = np.stack([world.min(axis=0), world.max(axis=0)])
        _read_only(m, bounds)
        instances.append(Instance(p, m, cast, receive, str(node), bounds))
    if not instances:
        detail = "; ".join(warnings) or "the scene has no geometry"
        raise SceneError(f"the scene has no triangles to render ({detail})")
    return Scene(primitives, instances, key=_built_key(primitives, instances),
                 warnings=warnings)


def _built_key(primitives: list[Primitive], instances: list[Instance]) -> str:
    """Content key of a scene built in memory: everything that changes its picture (geometry,
    material, texture, placement and shadow flags), as a file's key covers its bytes. The
    renderer's upload cache is keyed by it, so two scenes with one key must draw alike."""
    parts: list[bytes] = []
    for p in primitives:
        m = p.material
        parts += [a.tobytes() if a is not None else b"-"
                  for a in (p.positions, p.normals, p.indices, p.uv, p.colors, m.base_color,
                            m.texture)]
        # The texture's shape too: its bytes alone do not tell 2 x 8 texels from 4 x 4.
        shape = None if m.texture is None else m.texture.shape
        parts.append(f"{m.alpha_mode}:{m.alpha_cutoff!r}:{m.double_sided}:{m.unlit}:"
                     f"{m.sampler}:{shape}".encode())
    for i in instances:
        parts.append(i.matrix.tobytes())
        parts.append(np.array([i.primitive, i.cast_shadow, i.receive_shadow], np.int64).tobytes())
    # Each part length-prefixed, so that no two different scenes hash the same bytes.
    return "built:" + content_key(b"".join(len(x).to_bytes(8, "little") + x for x in parts))


def scene_from_meshes(meshes: list, names: list[str] | None = None) -> Scene:
    """Build a :class:`Scene` from trimesh meshes already in world space (tests, demo scenes).

    Parameters
    ----------
    meshes : list of trimesh.Trimesh
        ``mesh.metadata`` may hold ``castShadow`` / ``receiveShadow`` booleans.
    names : list of str, optional
        One per mesh.

    Raises
    ------
    SceneError
        No mesh, an item that is not a ``trimesh.Trimesh``, names not one per mesh, or a mesh
        :func:`scene_from_trimesh` would refuse.
    """
    import trimesh

    if isinstance(meshes, (str, bytes)) or not isinstance(meshes, Sequence):
        raise SceneError(f"meshes must be a list of trimesh.Trimesh, not a "
                         f"{type(meshes).__name__}")
    if names is not None and len(names) != len(meshes):
        raise SceneError(f"{len(names)} names for {len(meshes)} meshes")
    primitives, instances = [], []
    for i, mesh in enumerate(meshes):
        name = names[i] if names else f"mesh_{i}"
        if not isinstance(mesh, trimesh.Trimesh):
            raise SceneError(f"mesh {i} is a {type(mesh).__name__}, not a trimesh.Trimesh")
        prim = _primitive_from_trimesh(mesh, name)
        primitives.append(prim)
        meta = mesh.metadata if isinstance(mesh.metadata, dict) else {}
        matrix, bounds = np.eye(4), prim.local_bounds.astype(np.float64)
        _read_only(matrix, bounds)
        instances.append(
            Instance(
                primitive=i,
                matrix=matrix,
                cast_shadow=_flag(meta, "castShadow") is not False,
                receive_shadow=_flag(meta, "receiveShadow") is not False,
                name=name,
                bounds=bounds,
            )
        )
    if not instances:
        raise SceneError("the scene has no triangles to render")
    return Scene(primitives, instances, key=_built_key(primitives, instances))
