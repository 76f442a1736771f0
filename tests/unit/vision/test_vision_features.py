"""Feature extraction and the persisted blob."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vision_testkit import index_of, scene, shifted

from server.vision import (
    EngineParams,
    FeatureParams,
    HomingParams,
    ImageFeatures,
    extract,
    match_features,
)
from server.vision.features import (
    BINARY_DESCRIPTORS,
    DESCRIPTOR_BYTES,
    DESCRIPTOR_KINDS,
    DescriptorKind,
    descriptor_distances,
    extract_corners,
    grey_world,
    normalise,
    opencv_features,
    signature_blocks,
    signature_length,
)


def test_extract_shapes_and_dtypes() -> None:
    f = extract(scene(1))
    assert f.keypoints.dtype == np.float32 and f.keypoints.shape == (100, 2)
    assert f.descriptors.dtype == np.uint8 and f.descriptors.shape == (100, 36)
    assert f.signature.dtype == np.float32 and f.signature.shape == (signature_length(),)
    assert f.size == (320, 240)
    assert np.all((f.keypoints >= 0) & (f.keypoints < [320, 240]))


def test_signature_blocks_have_unit_norm() -> None:
    f = extract(scene(2))
    start = 0
    for name, n in signature_blocks():
        block = f.signature[start : start + n]
        start += n
        assert np.linalg.norm(block) == pytest.approx(1.0, abs=1e-4), name


@pytest.mark.parametrize("shape", [(480, 640, 3), (32, 64, 3), (120, 160), (241, 333, 3)])
def test_any_size_grey_or_colour(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=shape, dtype=np.uint8)
    f = extract(img)
    assert f.signature.shape == (signature_length(),)
    assert f.n_keypoints <= 100


def test_fifty_features_option_and_orb() -> None:
    f50 = extract(scene(3), FeatureParams(n_features=50))
    assert f50.n_keypoints == 50
    orb = extract(scene(3), FeatureParams(descriptor="orb"))
    assert orb.descriptor == "orb" and orb.descriptors.shape[1] == 32
    assert len(orb.signature) == signature_length(FeatureParams(descriptor="orb"))


@pytest.mark.parametrize(
    ("shape", "params"),
    [
        ((240, 320, 3), FeatureParams()),
        ((120, 160, 3), FeatureParams()),
        ((240, 320), FeatureParams(colour_constancy=False)),
        ((300, 400, 3), FeatureParams(descriptor="orb")),
        ((240, 320, 3), FeatureParams(descriptor="orb_fast")),
        ((300, 400, 3), FeatureParams(descriptor="sift")),
    ],
)
def test_extract_corners_gives_the_corners_and_descriptors_of_extract(
    shape: tuple[int, ...], params: FeatureParams
) -> None:
    img = (
        scene(5)
        if shape == (240, 320, 3)
        else np.random.default_rng(1).integers(0, 256, size=shape, dtype=np.uint8)
    )
    full, local = extract(img, params), extract_corners(img, params)
    assert local.n_keypoints > 0
    assert np.array_equal(local.keypoints, full.keypoints)
    assert np.array_equal(local.descriptors, full.descriptors)
    assert (local.descriptor, local.size, local.flags) == (full.descriptor, full.size, full.flags)
    assert local.signature.shape == (0,)


def test_blank_image_has_no_corners_but_a_signature() -> None:
    f = extract(np.full((240, 320, 3), 128, np.uint8))
    assert f.n_keypoints == 0 and f.descriptors.shape == (0, 36)
    assert np.all(np.isfinite(f.signature))


def test_rejects_bad_input_with_a_helpful_message() -> None:
    with pytest.raises(ValueError, match="uint8"):
        extract(np.zeros((10, 10), np.float32))
    with pytest.raises(ValueError, match="descriptor"):
        FeatureParams(descriptor="surf")  # type: ignore[arg-type]


def test_round_trip_of_real_features() -> None:
    f = extract(scene(4))
    g = ImageFeatures.from_bytes(f.to_bytes())
    assert g == f
    assert len(f.to_bytes()) < 6000


@settings(max_examples=30, deadline=None)
@given(
    k=st.integers(0, 100),
    d=st.sampled_from([32, 36]),
    s=st.integers(1, 600),
    seed=st.integers(0, 2**31),
)
def test_round_trip_property(k: int, d: int, s: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    f = ImageFeatures(
        keypoints=rng.uniform(0, 320, size=(k, 2)).astype(np.float32),
        descriptors=rng.integers(0, 256, size=(k, d), dtype=np.uint8),
        signature=rng.normal(size=s).astype(np.float32),
        descriptor="orb" if d == 32 else "grad36",
        size=(320, 240),
    )
    assert ImageFeatures.from_bytes(f.to_bytes()) == f


def test_from_bytes_rejects_foreign_or_corrupt_blobs() -> None:
    blob = extract(scene(5)).to_bytes()
    with pytest.raises(ValueError, match="magic"):
        ImageFeatures.from_bytes(b"XXXX" + blob[4:])
    with pytest.raises(ValueError, match="corrupt"):
        ImageFeatures.from_bytes(blob[:-3])
    with pytest.raises(ValueError, match="version"):
        ImageFeatures.from_bytes(blob[:4] + b"\x63\x00" + blob[6:])


def test_extraction_is_deterministic() -> None:
    assert extract(scene(6)) == extract(scene(6))


def _block(sig: np.ndarray, name: str, params: FeatureParams) -> np.ndarray:
    start = 0
    for block, length in signature_blocks(params):
        if block == name:
            return sig[start : start + length]
        start += length
    raise KeyError(name)


@pytest.mark.parametrize("seed", [1, 2, 7])
def test_grey_world_cancels_a_dimmer_warmer_light(seed: int) -> None:
    """The simulated home's lighting condition scales B, G, R by about 0.33, 0.52, 0.70."""
    img = scene(seed)
    dim = np.clip(img * np.array([0.33, 0.52, 0.70]), 0, 255).astype(np.uint8)
    dist = {}
    for constancy in (True, False):
        p = FeatureParams(colour_constancy=constancy)
        a, b = extract(img, p).signature, extract(dim, p).signature
        dist[constancy] = {
            name: float(np.linalg.norm(_block(a, name, p) - _block(b, name, p)))
            for name in ("hist", "thumb")
        }
    assert dist[True]["thumb"] < 0.05 < 0.3 < dist[False]["thumb"]
    # flat synthetic colours make peaky histograms: quantisation keeps some distance
    assert dist[True]["hist"] < 0.6 * dist[False]["hist"]


def test_grey_world_puts_every_channel_percentile_on_the_target() -> None:
    img = scene(3)
    out = grey_world(img, 180.0, 90.0)
    p90 = np.percentile(out.reshape(-1, 3), 90, axis=0)
    assert np.all(np.abs(p90 - 180.0) < 4.0)
    # a per-channel gain in the input changes nothing (up to rounding)
    dim = np.clip(img * np.array([0.5, 0.6, 0.8]), 0, 255).astype(np.uint8)
    assert np.abs(grey_world(dim, 180.0).astype(int) - out.astype(int)).mean() < 3.0
    black = np.zeros((8, 8, 3), np.uint8)
    assert np.array_equal(grey_world(black), black)


def test_features_remember_how_they_were_normalised() -> None:
    on, off = FeatureParams(), FeatureParams(colour_constancy=False)
    f = extract(scene(2), on)
    g = ImageFeatures.from_bytes(f.to_bytes())
    assert g.flags == on.flags != off.flags
    assert on.matches(g) and not off.matches(g)
    assert not FeatureParams(descriptor="orb").matches(g)


def _grad36_naive(grey: np.ndarray, keypoints: np.ndarray, p: FeatureParams) -> np.ndarray:
    """The grad36 definition written out per corner, cell and pixel (float64)."""
    import cv2

    g = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), p.blur_sigma).astype(np.float64)
    c = p.cell
    out = np.zeros((len(keypoints), 36))
    for k, (x, y) in enumerate(np.rint(keypoints).astype(int)):
        values = []
        for i in range(3):
            for j in range(3):
                sums = np.zeros(4)
                cx, cy = x + (j - 1) * c, y + (i - 1) * c
                for v in range(cy - c // 2, cy - c // 2 + c):
                    for u in range(cx - c // 2, cx - c // 2 + c):
                        gx = g[v, u + 1] - g[v, u - 1]
                        gy = g[v + 1, u] - g[v - 1, u]
                        sums += [max(gx, 0), max(-gx, 0), max(gy, 0), max(-gy, 0)]
                values.extend(sums)
        d = np.array(values)
        d = np.minimum(d / max(np.linalg.norm(d), 1e-6), p.clip)
        out[k] = d / max(np.linalg.norm(d), 1e-6)
    return np.clip(np.rint(out * 255.0 / p.clip), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_grad36_equals_the_naive_definition(seed: int) -> None:
    from server.vision.features import detect_corners, grad36_descriptors, normalise

    p = FeatureParams()
    _, grey = normalise(scene(seed), p)
    corners = detect_corners(grey, p)[:30]
    fast = grad36_descriptors(grey, corners, p).astype(int)
    naive = _grad36_naive(grey, corners, p).astype(int)
    # float32 against float64 sums: a byte may round the other way, never by more than 1
    assert np.abs(fast - naive).max() <= 1
    assert np.mean(fast != naive) < 0.01


def test_grad36_near_the_border_reads_a_mirrored_image() -> None:
    from server.vision.features import grad36_descriptors, normalise

    p = FeatureParams(border=2)
    _, grey = normalise(scene(4), p)
    corners = np.array([[0.0, 0.0], [319.0, 239.0], [3.0, 120.0], [160.0, 120.0]], np.float32)
    desc = grad36_descriptors(grey, corners, p)
    assert desc.shape == (4, 36) and desc.dtype == np.uint8
    inner = grad36_descriptors(grey, corners[3:], p)
    np.testing.assert_array_equal(desc[3], inner[0])  # padding does not change inner corners


# --- every descriptor option (FeatureParams.descriptor) ---------------------------------------


@pytest.mark.parametrize("kind", DESCRIPTOR_KINDS)
def test_each_descriptor_extracts_and_matches_a_shifted_copy(kind: DescriptorKind) -> None:
    """Keypoints and descriptors of every kind find a 6 px shift: RANSAC on the matches
    recovers the translation, with most matches as inliers."""
    p = FeatureParams(descriptor=kind)
    original, moved = extract(scene(3), p), extract(shifted(scene(3), 6), p)
    for f in (original, moved):
        assert f.descriptor == kind and 20 <= f.n_keypoints <= p.n_features
        assert f.keypoints.dtype == np.float32 and f.keypoints.shape == (f.n_keypoints, 2)
        assert f.descriptors.dtype == np.uint8
        assert f.descriptors.shape == (f.n_keypoints, DESCRIPTOR_BYTES[kind])
        assert np.all((f.keypoints >= 0) & (f.keypoints < [320, 240]))
        assert f.signature.shape == (signature_length(p),)
    src, dst = match_features(moved, original, params=HomingParams(features=p))
    h, mask = cv2.findHomography(src, dst, cv2.RANSAC, 2.0)
    assert h is not None and mask is not None
    assert int(mask.sum()) >= 20 and mask.mean() > 0.8
    # dst = src shifted back by 6 px: a pure translation
    np.testing.assert_allclose(h[:2, 2], [-6.0, 0.0], atol=0.6)
    np.testing.assert_allclose(h[:2, :2], np.eye(2), atol=0.01)


@pytest.mark.parametrize("geometric", [False, True])
@pytest.mark.parametrize("kind", DESCRIPTOR_KINDS)
def test_each_descriptor_ranks_the_shifted_copy_first(
    kind: DescriptorKind, geometric: bool
) -> None:
    p = EngineParams(features=FeatureParams(descriptor=kind), geometric=geometric)
    idx, _ = index_of([scene(s) for s in range(6)], list(range(6)), p)
    for i in (1, 4):
        sim = idx.query(extract(shifted(scene(i), 6), p.features))
        assert int(np.argmax(sim.image)) == i


@pytest.mark.parametrize("kind", DESCRIPTOR_KINDS)
def test_index_feature_errors_equal_the_mean_nearest_descriptor_distance(
    kind: DescriptorKind,
) -> None:
    """The index's batched second pass (vector kinds: squared distance, root after the min;
    binary kinds: Hamming from +-1 products) equals :func:`descriptor_distances` per pair."""
    p = EngineParams(features=FeatureParams(descriptor=kind))
    idx, feats = index_of([scene(s) for s in range(4)], [0, 1, 2, 3], p)
    query = extract(shifted(scene(2), 4), p.features)
    got = idx.feature_errors(query, np.arange(4, dtype=np.int64))
    for j, f in enumerate(feats):
        d = descriptor_distances(query.descriptors, f.descriptors, kind, p.features)
        want = 0.5 * (d.min(axis=1).mean() + d.min(axis=0).mean())
        assert got[j] == pytest.approx(want, abs=1e-4)
    assert int(np.argmin(got)) == 2


@pytest.mark.parametrize("kind", DESCRIPTOR_KINDS)
def test_descriptor_distances_are_zero_on_identical_and_larger_on_different(
    kind: DescriptorKind,
) -> None:
    p = FeatureParams(descriptor=kind)
    desc = extract(scene(8), p).descriptors
    d = descriptor_distances(desc, desc, kind, p)
    assert d.shape == (len(desc), len(desc)) and d.dtype == np.float32
    assert np.abs(np.diag(d)).max() < 2e-3
    same = np.all(desc[:, None] == desc[None, :], axis=2)
    distinct = ~same
    assert d[distinct].min() > 0.0
    # a descriptor with no duplicate is nearest to itself (one byte apart: 0.001 for grad36)
    unique = same.sum(axis=1) == 1
    assert np.array_equal(d.argmin(axis=1)[unique], np.flatnonzero(unique))
    assert 0.2 < float(np.median(d[distinct])) < 1.5  # normalised to about [0, 1]
    # naive reference: Hamming over the bits, or L2 of the unit-scaled vectors
    a, b = desc[:5], desc[5:9]
    if kind in BINARY_DESCRIPTORS:
        bits = np.unpackbits(a[:, None] ^ b[None], axis=2).sum(axis=2)
        want = bits / (8.0 * a.shape[1])
    else:
        s = p.descriptor_scale
        want = np.linalg.norm(a[:, None].astype(float) * s - b[None].astype(float) * s, axis=2)
    np.testing.assert_allclose(descriptor_distances(a, b, kind, p), want, atol=1e-4)


@pytest.mark.parametrize("kind", DESCRIPTOR_KINDS)
def test_blob_round_trip_of_every_descriptor(kind: DescriptorKind) -> None:
    p = FeatureParams(descriptor=kind)
    f = extract(scene(4), p)
    blob = f.to_bytes()
    assert blob[6] == DESCRIPTOR_KINDS.index(kind)  # the kind's position in DESCRIPTOR_KINDS
    assert ImageFeatures.from_bytes(blob) == f
    assert p.matches(ImageFeatures.from_bytes(blob))


@pytest.mark.parametrize(("kind_index", "kind", "d"), [(0, "grad36", 36), (1, "orb", 32)])
def test_blobs_written_before_the_new_descriptors_still_load(
    kind_index: int, kind: DescriptorKind, d: int
) -> None:
    """A version-2 blob packed by hand as the code before the new kinds wrote it."""
    import struct

    rng = np.random.default_rng(kind_index)
    kp = rng.uniform(0, 300, (3, 2)).astype("<f4")
    desc = rng.integers(0, 256, (3, d), dtype=np.uint8)
    sig = rng.normal(size=600 if d == 36 else 592).astype("<f4")
    header = struct.pack("<4sHBBHHHHH", b"TRVF", 2, kind_index, 1, 3, d, len(sig), 320, 240)
    f = ImageFeatures.from_bytes(header + kp.tobytes() + desc.tobytes() + sig.tobytes())
    assert (f.descriptor, f.flags, f.size) == (kind, 1, (320, 240))
    np.testing.assert_array_equal(f.keypoints, kp)
    np.testing.assert_array_equal(f.descriptors, desc)
    np.testing.assert_array_equal(f.signature, sig)


@pytest.mark.parametrize("kind", DESCRIPTOR_KINDS)
def test_signature_blocks_of_every_descriptor(kind: DescriptorKind) -> None:
    p = FeatureParams(descriptor=kind)
    f = extract(scene(2), p)
    sizes = dict(signature_blocks(p))
    assert sizes["desc_mean"] == sizes["desc_var"] == DESCRIPTOR_BYTES[kind]
    for name in sizes:
        assert np.linalg.norm(_block(f.signature, name, p)) == pytest.approx(1.0, abs=1e-4)
    values = (
        np.unpackbits(f.descriptors, axis=1).reshape(f.n_keypoints, -1, 8).sum(axis=2)
        if kind in BINARY_DESCRIPTORS
        else f.descriptors.astype(np.float64)
    )
    mean = values.mean(axis=0)
    np.testing.assert_allclose(
        _block(f.signature, "desc_mean", p), mean / np.linalg.norm(mean), atol=1e-5
    )


def test_sift_bytes_are_opencv_s_float_values_exactly() -> None:
    """OpenCV's float SIFT values are whole numbers in [0, 255] (unit vector x 512,
    saturated): the uint8 descriptors lose nothing."""
    p = FeatureParams(descriptor="sift")
    _, grey = normalise(scene(6), p)
    kps, ref = cv2.SIFT.create(nfeatures=p.n_features).detectAndCompute(grey, None)
    assert np.array_equal(ref, np.rint(ref)) and ref.min() >= 0 and ref.max() <= 255
    pts, desc = opencv_features(grey, p)
    # same keypoints, ours ordered by response: match rows by position
    ref_pts = cv2.KeyPoint.convert(kps)
    for q, row in zip(pts[:20], desc[:20], strict=True):
        hits = np.flatnonzero(np.all(ref_pts == q, axis=1))
        assert any(np.array_equal(ref[h].astype(np.uint8), row) for h in hits)
    norms = np.linalg.norm(desc.astype(np.float64), axis=1)
    assert np.all(np.abs(norms * p.descriptor_scale - 1.0) < 0.05)


@pytest.mark.parametrize("kind", ["orb_fast", "sift", "akaze", "akaze_upright", "brisk"])
def test_own_detector_kinds_keep_at_most_n_features_strongest_first(kind: DescriptorKind) -> None:
    # scene 3: every detector finds more than 30 keypoints there (AKAZE, which has no budget
    # of its own, finds 23 in scene 1)
    few = extract(scene(3), FeatureParams(descriptor=kind, n_features=30))
    many = extract(scene(3), FeatureParams(descriptor=kind, n_features=200))
    assert 25 <= few.n_keypoints <= 30 < many.n_keypoints <= 200
    if kind != "orb_fast":  # these keep the best by response: the 30 are the 200's first 30
        # (as sets: the synthetic scene has keypoints of equal response)
        assert {tuple(x) for x in few.keypoints} == {tuple(x) for x in many.keypoints[:30]}
    blank = np.full((240, 320, 3), 90, np.uint8)
    assert extract(blank, FeatureParams(descriptor=kind)).n_keypoints == 0


def test_teblid_describes_the_harris_corners_of_grad36() -> None:
    """``teblid`` is a descriptor only: its keypoints are grad36's Harris corners (the same
    16 px border), and its bytes are OpenCV's TEBLID at those corners, upright."""
    img = scene(7)
    g36 = extract(img, FeatureParams())
    teb = extract(img, FeatureParams(descriptor="teblid"))
    np.testing.assert_array_equal(teb.keypoints, g36.keypoints)
    _, grey = normalise(img, FeatureParams(descriptor="teblid"))
    kps = [cv2.KeyPoint(float(x), float(y), 31.0) for x, y in g36.keypoints[:10]]
    teblid = cv2.xfeatures2d.TEBLID.create(1.0, cv2.xfeatures2d.TEBLID_SIZE_256_BITS)
    _, ref = teblid.compute(grey, kps)
    np.testing.assert_array_equal(teb.descriptors[:10], ref)


def test_brisk_is_the_same_on_concurrent_threads() -> None:
    """BRISK's detector is kept per thread (it is dear to create): extraction on several
    threads at once gives what it gives alone."""
    from concurrent.futures import ThreadPoolExecutor

    p = FeatureParams(descriptor="brisk")
    images = [scene(s) for s in range(6)]
    alone = [extract(im, p) for im in images]
    with ThreadPoolExecutor(3) as pool:
        together = list(pool.map(lambda im: extract(im, p), images * 2))
    assert together == alone + alone


def test_a_missing_contrib_class_says_which_package_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delattr(cv2.xfeatures2d, "AKAZE")
    monkeypatch.delattr(cv2, "AKAZE", raising=False)
    with pytest.raises(RuntimeError, match="opencv-contrib-python-headless"):
        extract(scene(1), FeatureParams(descriptor="akaze"))


def test_opencv_is_the_contrib_build_and_alone() -> None:
    """The project depends on opencv-contrib-python-headless (AKAZE, BRISK, TEBLID); another
    OpenCV wheel installed beside it would overwrite the same ``cv2`` package."""
    from importlib import metadata

    installed = {
        name
        for name in (
            "opencv-python",
            "opencv-python-headless",
            "opencv-contrib-python",
            "opencv-contrib-python-headless",
        )
        if _installed(metadata, name)
    }
    assert installed == {"opencv-contrib-python-headless"}


def _installed(metadata: object, name: str) -> bool:
    import importlib.metadata as md

    try:
        md.distribution(name)
    except md.PackageNotFoundError:
        return False
    return True
