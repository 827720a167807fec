"""Shadow-error metrics: how far a rendered visibility image is from the ray-traced reference.

Both images are reduced to shadow masks (visibility < 0.5) over the pixels where the comparison
means something (the reference's ``valid`` mask, finite in both). The numbers separate the two
classic shadow-map failures: false shadow (acne, over-biased self-shadowing) and missed shadow
(light leaking, peter-panning), plus where the shadow boundary sits (edge distance).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .errors import ReferenceUnavailable
from .reference import ReferenceResult


@dataclass
class ShadowMetrics:
    """Agreement of one light's rendered shadow mask with the reference.

    Attributes
    ----------
    iou : float
        |R ∧ T| / |R ∨ T| of the shadow masks (rendered R, truth T); 1.0 when both are empty.
    misclassified_pct : float
        Percentage of evaluated pixels whose shadow state differs.
    false_shadow_pct : float
        Percentage of truly lit pixels rendered as shadowed (acne); 0 when none are lit.
    missed_shadow_pct : float
        Percentage of truly shadowed pixels rendered as lit (leaks, peter-panning); 0 when none.
    edge_distance_px : float
        Symmetric mean distance in pixels between the two masks' shadow boundaries; NaN when
        neither mask has a boundary, the image diagonal when only one has.
    pixels : int
        Number of evaluated pixels.
    """

    iou: float
    misclassified_pct: float
    false_shadow_pct: float
    missed_shadow_pct: float
    edge_distance_px: float
    pixels: int

    def to_dict(self) -> dict:
        """Plain JSON-ready dict; NaN becomes None (JSON has no NaN)."""
        out = asdict(self)
        for k, v in out.items():
            if isinstance(v, float) and not math.isfinite(v):
                out[k] = None
        return out


def _edges(mask: np.ndarray, evaluated: np.ndarray) -> np.ndarray:
    """Mask pixels with an evaluated 4-neighbour outside the mask.

    Parameters
    ----------
    mask, evaluated : ndarray, shape (H, W), bool

    Returns
    -------
    ndarray, shape (H, W), bool
    """
    outside = evaluated & ~mask
    nb = np.zeros_like(mask)
    nb[1:, :] |= outside[:-1, :]
    nb[:-1, :] |= outside[1:, :]
    nb[:, 1:] |= outside[:, :-1]
    nb[:, :-1] |= outside[:, 1:]
    return mask & nb


def _edge_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over both edge sets of the distance to the nearest edge pixel of the other set."""
    na, nb = int(a.sum()), int(b.sum())
    if na == 0 and nb == 0:
        return math.nan
    if na == 0 or nb == 0:
        return float(math.hypot(*a.shape))
    # scipy comes with the reference extra, not with the service, which never needs metrics.
    try:
        from scipy import ndimage
    except ImportError as exc:
        raise ReferenceUnavailable(
            "the shadow metrics need scipy: pip install 'shadowmap-service[reference]' "
            f"(or pip install scipy); import failed with: {exc}"
        ) from None
    # distance_transform_edt measures the distance to the nearest zero, i.e. to an edge pixel.
    to_b = ndimage.distance_transform_edt(~b)
    to_a = ndimage.distance_transform_edt(~a)
    return float((to_b[a].sum() + to_a[b].sum()) / (na + nb))


def shadow_metrics(rendered: np.ndarray, reference: np.ndarray, valid: np.ndarray) -> ShadowMetrics:
    """Compare a rendered visibility image with the reference for one light.

    Parameters
    ----------
    rendered, reference : ndarray, shape (H, W), float
        Visibility in [0, 1] (NaN allowed: such pixels are not evaluated).
    valid : ndarray, shape (H, W), bool
        Pixels where the comparison is meaningful (:attr:`ReferenceResult.valid`).

    Returns
    -------
    ShadowMetrics
    """
    rendered = np.asarray(rendered, np.float64)
    reference = np.asarray(reference, np.float64)
    valid = np.asarray(valid, bool)
    if rendered.shape != reference.shape or valid.shape != reference.shape or rendered.ndim != 2:
        raise ValueError(
            f"shapes differ or are not 2-D: rendered {rendered.shape}, "
            f"reference {reference.shape}, valid {valid.shape}"
        )
    ev = valid & np.isfinite(rendered) & np.isfinite(reference)
    r = ev & (rendered < 0.5)
    t = ev & (reference < 0.5)
    n = int(ev.sum())
    inter = int((r & t).sum())
    union = int((r | t).sum())
    false_shadow = int((r & ~t).sum())
    missed = int((~r & t).sum())
    truly_lit = n - int(t.sum())
    truly_shadowed = int(t.sum())
    return ShadowMetrics(
        iou=inter / union if union else 1.0,
        misclassified_pct=100.0 * (false_shadow + missed) / n if n else 0.0,
        false_shadow_pct=100.0 * false_shadow / truly_lit if truly_lit else 0.0,
        missed_shadow_pct=100.0 * missed / truly_shadowed if truly_shadowed else 0.0,
        edge_distance_px=_edge_distance(_edges(r, ev), _edges(t, ev)),
        pixels=n,
    )


def compare_all(rendered: np.ndarray, ref: ReferenceResult) -> list[ShadowMetrics]:
    """Metrics for every light.

    Parameters
    ----------
    rendered : ndarray, shape (H, W, L)
        Rendered visibility, lights in the same order as the reference.
    ref : ReferenceResult

    Returns
    -------
    list of ShadowMetrics, length L
    """
    rendered = np.asarray(rendered)
    if rendered.ndim == 2:
        rendered = rendered[..., None]
    if rendered.shape != ref.visibility.shape:
        raise ValueError(
            f"rendered visibility {rendered.shape} does not match the reference "
            f"{ref.visibility.shape}"
        )
    return [
        shadow_metrics(rendered[..., k], ref.visibility[..., k], ref.valid[..., k])
        for k in range(rendered.shape[2])
    ]
