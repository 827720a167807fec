"""The one content hash and the one bounded cache the library keeps scenes in.

A scene is known by :func:`content_key` of its file and external resources, computed once per
load; the parsed scene and its GPU upload are both cached under that key in
:class:`BoundedCache` instances owned by the :class:`~shadowmap.renderer.Renderer`.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping
from typing import Generic, TypeVar

V = TypeVar("V")


def content_key(data: bytes, resources: Mapping[str, bytes] | None = None) -> str:
    """SHA-256 (hex) of a scene file and its resources (by sorted name), the cache key of a scene.

    Parameters
    ----------
    data : bytes
        The ``.glb`` or ``.gltf`` file.
    resources : mapping of str to bytes, optional
        External buffers and images by the relative name the file uses.
    """
    digest = hashlib.sha256(data)
    for name in sorted(resources or {}):
        digest.update(b"\0" + name.encode() + b"\0" + resources[name])  # type: ignore[index]
    return digest.hexdigest()


def parts_key(parts: list[bytes]) -> str:
    """:func:`content_key` of several byte strings, each framed by its length (so that no two
    different lists of parts join to the same bytes)."""
    return content_key(b"".join(len(p).to_bytes(8, "little") + p for p in parts))


class BoundedCache(Generic[V]):
    """Least-recently-used values by key, bounded by a count and, optionally, a size in bytes.

    Parameters
    ----------
    max_entries : int
        0 disables the cache: :meth:`get_or_make` then always makes and keeps nothing.
    max_bytes : int, optional
        Upper bound of ``sum(size(v))``; the newest entry is kept even when it alone is larger.
    size : callable, optional
        Bytes held by a value (needed with ``max_bytes``).
    on_evict : callable, optional
        Called with each value dropped from the cache (e.g. to free GPU memory).
    """

    def __init__(self, max_entries: int, max_bytes: int | None = None,
                 size: Callable[[V], int] | None = None,
                 on_evict: Callable[[V], None] | None = None) -> None:
        self.max_entries = max(int(max_entries), 0)
        self.max_bytes = max_bytes
        self._size = size or (lambda v: 0)
        self._on_evict = on_evict
        self._items: OrderedDict[str, V] = OrderedDict()
        self.hits = 0
        self.misses = 0

    @property
    def enabled(self) -> bool:
        return self.max_entries > 0 and (self.max_bytes is None or self.max_bytes > 0)

    def get_or_make(self, key: str, make: Callable[[], V]) -> tuple[V, bool, bool]:
        """The value of ``key``, made with ``make()`` on a miss.

        Returns
        -------
        value, kept, hit : V, bool, bool
            ``kept``: the value is owned by the cache (the caller must not free it).
        """
        if not self.enabled or not key:
            self.misses += 1
            return make(), False, False
        value = self._items.get(key)
        if value is not None:
            self._items.move_to_end(key)
            self.hits += 1
            return value, True, True
        self.misses += 1
        value = self._items[key] = make()
        self._trim()
        return value, True, False

    def get(self, key: str) -> V | None:
        """The value of ``key`` (marked recently used), or None; counted as a hit or a miss."""
        value = self._items.get(key) if self.enabled and key else None
        if value is None:
            self.misses += 1
            return None
        self._items.move_to_end(key)
        self.hits += 1
        return value

    def put(self, key: str, value: V) -> bool:
        """Keep ``value`` under ``key``, evicting the oldest entries beyond the bounds.

        Returns False, keeping nothing, when the cache is disabled, ``key`` is empty, or the value
        alone is larger than ``max_bytes`` (the caller still owns it then).
        """
        if not self.enabled or not key or key in self._items:
            return False
        if self.max_bytes is not None and self._size(value) > self.max_bytes:
            return False
        self._items[key] = value
        self._trim()
        return True

    def discard(self, key: str) -> None:
        """Forget ``key`` (not evicted: ``on_evict`` is not called; the caller owns the value)."""
        self._items.pop(key, None)

    def _trim(self) -> None:
        while len(self._items) > 1 and (
            len(self._items) > self.max_entries
            or (self.max_bytes is not None and self.nbytes > self.max_bytes)
        ):
            _, old = self._items.popitem(last=False)
            if self._on_evict is not None:
                self._on_evict(old)

    @property
    def nbytes(self) -> int:
        return sum(self._size(v) for v in self._items.values())

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: object) -> bool:
        return key in self._items

    def values(self) -> Iterator[V]:
        return iter(list(self._items.values()))

    def clear(self) -> None:
        """Drop every entry (calling ``on_evict`` for each)."""
        items = list(self._items.values())
        self._items.clear()
        if self._on_evict is not None:
            for v in items:
                self._on_evict(v)
