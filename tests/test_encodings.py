"""Depth encodings: CPU mirrors, GLSL encode/decode round trips, and exact compares on tiny maps."""

from __future__ import annotations

import numpy as np
import pytest

from shadowmap.renderer import encodings
from shadowmap.renderer.params import ENCODINGS

PACKED = [e for e in ENCODINGS if e != "depth"]
rng = np.random.default_rng(7)
DEPTHS = np.concatenate([rng.random(4096), [0.0, 1e-7, 0.5, 1 - 2**-24, 1.0]])


@pytest.mark.parametrize("encoding", PACKED)
def test_cpu_round_trip_within_one_step(encoding):
    t = DEPTHS
    back = encodings.decode(encodings.encode(t, encoding), encoding)
    assert np.max(np.abs(back - np.clip(t, 0, 1))) <= encodings.STEP[encoding]


@pytest.mark.parametrize("encoding", PACKED)
def test_cpu_encoding_is_monotonic(encoding):
    t = np.sort(DEPTHS)
    back = encodings.decode(encodings.encode(t, encoding), encoding)
    assert np.all(np.diff(back) >= 0)


def test_r8_step_is_what_the_webgl_guide_describes():
    # One 8-bit channel: depths 0.3/255 apart within one step read back the same.
    t = np.array([31.1 / 255, 31.4 / 255])
    back = encodings.decode(encodings.encode(t, "r8"), "r8")
    assert back[0] == back[1]


@pytest.mark.gl
@pytest.mark.parametrize("encoding", PACKED)
def test_gpu_encoder_matches_cpu_bytes(renderer, encoding):
    from probes import gpu_encode

    t = DEPTHS[:4096].reshape(64, 64)
    stored = gpu_encode(renderer, t, encoding)
    back = encodings.decode(stored, encoding)
    # The GPU works in float32: compare against the float32 depth it was given.
    t32 = t.astype(np.float32).astype(np.float64)
    assert np.max(np.abs(back - t32)) <= encodings.STEP[encoding]


@pytest.mark.gl
@pytest.mark.parametrize("encoding", PACKED)
def test_gpu_decoder_inverts_cpu_encoder(renderer, encoding):
    from probes import gpu_decode

    t = DEPTHS[:4096].reshape(64, 64)
    back = gpu_decode(renderer, encodings.encode(t, encoding), encoding)
    assert np.max(np.abs(back - t)) <= encodings.STEP[encoding] + 2**-23


# A 3x3 map of linear depths whose compare results are known exactly.
MAP3 = np.array(
    [
        [0.20, 0.50, 0.80],
        [0.30, 0.60, 0.90],
        [0.40, 0.70, 1.00],
    ]
)


def _centre(i, j, s=3):
    return ((j + 0.5) / s, (i + 0.5) / s)


@pytest.mark.gl
@pytest.mark.parametrize("encoding", list(ENCODINGS))
def test_hard_compare_on_3x3_map(renderer, encoding):
    from probes import gpu_compare

    queries, expected = [], []
    step = max(encodings.STEP[encoding], 1e-6) * 2
    for i in range(3):
        for j in range(3):
            u, v = _centre(i, j)
            d = MAP3[i, j]
            queries += [(u, v, d - 0.05), (u, v, d + 0.05), (u, v, d - step)]
            expected += [1.0, 0.0 if d < 1.0 else 0.0, 1.0]
    got = gpu_compare(renderer, MAP3, np.array(queries), encoding)
    np.testing.assert_array_equal(got, np.array(expected, np.float32))


@pytest.mark.gl
@pytest.mark.parametrize("encoding", PACKED)
def test_pcf_counts_texels_in_front_of_the_receiver(renderer, encoding):
    from probes import gpu_compare

    # At the centre texel, a 3x3 kernel sees all nine depths: the lit fraction is the number of
    # texels at or beyond the reference, over nine.
    u, v = _centre(1, 1)
    refs = [0.1, 0.35, 0.55, 0.65, 0.75, 0.95]
    got = gpu_compare(renderer, MAP3, np.array([(u, v, r) for r in refs]), encoding, pcf_radius=1)
    expected = [(MAP3 >= r).sum() / 9 for r in refs]
    np.testing.assert_allclose(got, expected, atol=1e-6)


@pytest.mark.gl
def test_depth_texture_compare_is_leq(renderer):
    from probes import gpu_compare

    u, v = _centre(0, 0)
    got = gpu_compare(renderer, MAP3, np.array([(u, v, 0.2), (u, v, 0.2 + 1e-4)]), "depth")
    np.testing.assert_array_equal(got, [1.0, 0.0])


@pytest.mark.gl
@pytest.mark.parametrize("encoding", ["depth", "rgba8", "rgb8"])
@pytest.mark.parametrize("pcf_radius", [0, 1, 2])
def test_receiver_plane_meets_its_own_depth_at_every_texel(renderer, encoding, pcf_radius):
    """A tilted plane stored at texel centres and looked up anywhere on that plane, with its
    slope and no bias at all: every texel the filter reads is compared against the plane at that
    texel's own centre, so the plane is lit everywhere, and shadowed just behind itself."""
    from probes import gpu_compare

    s, base, du, dv = 16, 0.3, 0.01, 0.02  # depth change per texel along u and v
    i, j = np.mgrid[0:s, 0:s]
    plane = base + du * (j + 0.5) + dv * (i + 0.5)
    uv = np.random.default_rng(3).uniform(0.2, 0.8, (64, 2))
    on = base + du * uv[:, 0] * s + dv * uv[:, 1] * s
    step = max(encodings.STEP[encoding], 1e-6) * 2
    for offset, want in ((-step, 1.0), (8 * step + 1e-4, 0.0)):
        q = np.c_[uv, on + offset, np.full(len(uv), du)]
        got = gpu_compare(renderer, plane, q, encoding, pcf_radius=pcf_radius, dref_v=dv)
        np.testing.assert_allclose(got, want, atol=1e-6)
    # Without the slope, half the texels around a lookup lie in front of it: acne.
    q = np.c_[uv, on - step, np.zeros(len(uv))]
    flat = gpu_compare(renderer, plane, q, encoding, pcf_radius=pcf_radius)
    assert flat.mean() < 0.9
