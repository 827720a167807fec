"""The request model on its own (no GL): structural validation."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from shadowmap.renderer import RenderParams


@pytest.mark.parametrize("request_", [
    {"lights": [{"direction": [float("nan"), -1, 0]}]},
    {"camera": {"eye": [float("inf"), 1, 1], "target": [0, 0, 0]}},
    {"camera": {"pose": [[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}},
])
def test_non_finite_numbers_are_refused(request_):
    with pytest.raises(ValidationError):
        RenderParams(**request_)
