"""Per-image features: Harris corners with a compact descriptor, and the global signature.

001 section 5.1 (features) and 5.2 (signatures). One call, :func:`extract`, turns a frame of any
size into an :class:`ImageFeatures`; :meth:`ImageFeatures.to_bytes` is the blob storage persists
per image so that a restart never re-extracts.

Steps of :func:`extract`:

1. **Normalise** the frame to the working size (default 320x240 px; INTER_AREA when shrinking,
   INTER_LINEAR when enlarging), then (``colour_constancy``, on by default) scale each colour
   channel of the image the colour blocks read so that a high percentile of it lands on a
   fixed grey level (a robust "grey world", :func:`grey_world`). A change of light
   that multiplies each channel by a gain (dimmer, warmer, a different bulb) cancels out, so
   the histogram and thumbnail compare the scene, not the lamp. Every pixel coordinate in this
   module is at the working size.
2. **Keypoints and descriptors**, at most ``n_features`` (100 by default, chosen by the
   benchmark; 50 as in the paper is the faster option), strongest first, chosen by
   ``FeatureParams.descriptor`` (:data:`DESCRIPTOR_KINDS`):

   * ``"grad36"`` (default, the paper's 36 bytes of neighbouring-pixel gradients) at **Harris
     corners** (``cv2.goodFeaturesToTrack`` with the Harris response, away from the border): a
     3x3 grid of cells around the corner, in each cell the summed positive and negative x and y
     gradients (4 values), L2-normalised, clipped and quantised to ``uint8``. Euclidean distance.
   * ``"orb"``: the 32-byte upright ORB/BRIEF binary descriptor at the same Harris corners,
     Hamming distance.
   * ``"orb_fast"``: OpenCV's ORB as it comes: its own FAST keypoints over an 8-level pyramid
     (scale 1.2), ranked by the Harris score, with the oriented (rotation-invariant) 32-byte
     descriptor. Hamming distance.
   * ``"sift"``: OpenCV's SIFT keypoints (difference of Gaussians, scale and orientation) and
     128-value descriptors. OpenCV computes each as a unit vector times 512, saturated to
     [0, 255] and rounded, so storing it as ``uint8`` loses nothing (``CV_8U`` gives the same
     bytes). Euclidean distance of the vectors divided by 512 (unit norm).
   * ``"akaze"``: OpenCV's AKAZE as it comes: its own keypoints (Hessian extrema in a
     nonlinear scale space, 4 octaves, response threshold 0.001), oriented 61-byte MLDB binary
     descriptor. Hamming. It has no keypoint budget: an image may give fewer than
     ``n_features``.
   * ``"akaze_upright"``: the same keypoints with OpenCV's upright MLDB descriptor (no
     orientation: the robot's camera does not roll).
   * ``"brisk"``: OpenCV's BRISK as it comes: its own keypoints (AGAST corners over scale
     octaves), oriented 64-byte binary descriptor. Hamming.
   * ``"teblid"``: the 32-byte (256-bit) TEBLID descriptor (Suárez et al., RA-L 2021: boxes of
     average grey levels compared pairwise, learned with triplet loss) at the same Harris
     corners as ``grad36``, upright (keypoint size 31 px, scale factor 1 as for ORB
     keypoints). Hamming.

   AKAZE, BRISK and TEBLID come from opencv_contrib (``cv2.xfeatures2d`` in OpenCV 5, in
   ``cv2`` for AKAZE and BRISK in 4.x): the project depends on
   ``opencv-contrib-python-headless``, never beside ``opencv-python-headless``. The benchmarks
   (``teachrepeat bench retrieval`` and ``teachrepeat bench features``, docs/retrieval.md)
   chose the default.
3. **Global signature**: the concatenation of unit-L2-norm blocks (see :func:`signature_blocks`):

   * ``hist``: YCbCr histogram, 64 bins per channel, square-rooted (Hellinger), stored as its
     orthonormal DCT coefficients per channel (192 values; all 64 kept by default, which is
     the plain histogram distance; ``hist_coefficients=16`` low-pass filters the histograms and
     makes the first pass read 4x fewer bytes, at a measured cost in recall);
   * ``thumb``: 8x6x3 colour thumbnail, mean removed (brightness invariant), 144 values;
   * ``desc_mean``, ``desc_var``: mean and variance of the descriptor values (D + D values: the
     bytes of grad36 and SIFT; the per-byte bit counts of the binary kinds);
   * ``patch``: a patch-normalised grey thumbnail (16x12; each pixel minus the mean over a local
     window, divided by its standard deviation, as in SeqSLAM), 192 values. Beyond the paper:
     it carries most of the weight on low-texture and low-resolution images.

   Every block has unit norm (or is all zero when undefined, e.g. no corners), so the squared
   Euclidean distance of a block lies in [0, 4].
"""

from __future__ import annotations

import functools
import struct
import threading
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

import cv2
import numpy as np
import numpy.typing as npt

DescriptorKind = Literal[
    "grad36", "orb", "orb_fast", "sift", "akaze", "akaze_upright", "brisk", "teblid"
]
#: Every descriptor option. The blob (:meth:`ImageFeatures.to_bytes`) stores the position in
#: this tuple: new kinds are appended, never inserted.
DESCRIPTOR_KINDS: tuple[DescriptorKind, ...] = get_args(DescriptorKind)
#: Bytes per descriptor (D) of each kind.
DESCRIPTOR_BYTES: dict[str, int] = {
    "grad36": 36,
    "orb": 32,
    "orb_fast": 32,
    "sift": 128,
    "akaze": 61,
    "akaze_upright": 61,
    "brisk": 64,
    "teblid": 32,
}
#: Kinds compared by Hamming distance; the others are vectors compared by Euclidean distance.
BINARY_DESCRIPTORS: frozenset[str] = frozenset(
    {"orb", "orb_fast", "akaze", "akaze_upright", "brisk", "teblid"}
)
#: Kinds at Harris corners (:func:`detect_corners`); the others bring their own detector.
HARRIS_DESCRIPTORS: frozenset[str] = frozenset({"grad36", "orb", "teblid"})
#: Nominal L2 norm of an OpenCV SIFT descriptor in byte units.
SIFT_NORM = 512.0

#: Names of the signature blocks, in the order they are concatenated.
SIGNATURE_BLOCKS: tuple[str, ...] = ("hist", "thumb", "desc_mean", "desc_var", "patch")

_MAGIC = b"TRVF"
#: Version of the ``to_bytes`` layout; bump it when the layout changes.
FORMAT_VERSION = 2
#: ``flags`` bit of :class:`ImageFeatures`: extracted with grey-world colour normalisation.
FLAG_COLOUR_CONSTANCY = 1
_HEADER = struct.Struct("<4sHBBHHHHH")


@dataclass(frozen=True)
class FeatureParams:
    """How an image is turned into features. All sizes in pixels at the working size.

    Attributes:
        width, height: working size every frame is resized to (px).
        n_features: keypoints kept per image, strongest detector response first. The paper
            uses 50; the benchmark (docs/retrieval.md) chose 100 as the default (corridor
            recall@1 0.75 -> 0.91); 50 is the faster option.
        descriptor: one of :data:`DESCRIPTOR_KINDS`: ``"grad36"`` (36-byte gradient descriptor
            at Harris corners), ``"orb"`` (32-byte upright ORB at Harris corners),
            ``"orb_fast"`` (OpenCV ORB: FAST keypoints, oriented 32-byte descriptor),
            ``"sift"`` (OpenCV SIFT: 128 bytes), ``"akaze"`` (OpenCV AKAZE: 61-byte MLDB),
            ``"akaze_upright"`` (the same, upright), ``"brisk"`` (OpenCV BRISK: 64 bytes),
            ``"teblid"`` (32-byte TEBLID at Harris corners). See the module docstring.
        harris_k: Harris detector free parameter (Harris kinds only, as the next four).
        harris_block: neighbourhood size of the Harris structure tensor (px).
        quality: minimum corner response relative to the strongest one in the image.
        min_distance: minimum distance between two kept corners (px).
        border: corners closer than this to the image border are dropped (px); must leave room
            for the descriptor patch (grad36: 1.5 * cell + 2; ORB and TEBLID: 16).
        cell: side of one of the 3x3 grad36 cells (px).
        blur_sigma: Gaussian blur before the grad36 gradients (px).
        clip: grad36 per-component clip after L2 normalisation (as in SIFT).
        hist_bins: histogram bins per YCbCr channel.
        hist_coefficients: DCT coefficients kept per channel (<= hist_bins).
        thumb_size: (columns, rows) of the colour thumbnail.
        patch_size: (columns, rows) of the patch-normalised grey thumbnail.
        patch_window: side of the local normalisation window, in thumbnail pixels (odd).
        colour_constancy: scale each channel so that its ``colour_percentile``-th percentile
            is ``colour_target`` before anything else (:func:`grey_world`), so that a change
            of light (a per-channel gain) cancels. Figures: ``teachrepeat bench
            sim-retrieval`` and docs/retrieval.md.
        colour_target: grey level (0-255) the percentile of every channel is scaled to.
        colour_percentile: which percentile of each channel sets its gain.
    """

    width: int = 320
    height: int = 240
    n_features: int = 100
    descriptor: DescriptorKind = "grad36"
    harris_k: float = 0.04
    harris_block: int = 3
    quality: float = 1e-3
    min_distance: float = 5.0
    border: int = 16
    cell: int = 6
    blur_sigma: float = 1.0
    clip: float = 0.3
    hist_bins: int = 64
    hist_coefficients: int = 64
    thumb_size: tuple[int, int] = (8, 6)
    patch_size: tuple[int, int] = (16, 12)
    patch_window: int = 5
    colour_constancy: bool = True
    colour_target: float = 160.0
    colour_percentile: float = 90.0

    def __post_init__(self) -> None:
        if self.descriptor not in DESCRIPTOR_KINDS:
            raise ValueError(
                f"unknown descriptor {self.descriptor!r}; choose one of {DESCRIPTOR_KINDS}"
            )
        if self.n_features < 1:
            raise ValueError("n_features must be at least 1")
        if self.width < 2 * self.border + 8 or self.height < 2 * self.border + 8:
            raise ValueError(
                f"working size {self.width}x{self.height} too small for border {self.border}"
            )
        if not 1 <= self.hist_coefficients <= self.hist_bins or self.hist_bins % 2:
            raise ValueError("hist_bins must be even and 1 <= hist_coefficients <= hist_bins")
        if self.patch_window % 2 == 0:
            raise ValueError("patch_window must be odd")
        if not 0.0 < self.colour_target <= 255.0:
            raise ValueError("colour_target must lie in (0, 255] grey levels")
        if not 0.0 < self.colour_percentile < 100.0:
            raise ValueError("colour_percentile must lie in (0, 100)")

    @property
    def descriptor_bytes(self) -> int:
        """Bytes per descriptor (D)."""
        return DESCRIPTOR_BYTES[self.descriptor]

    @property
    def binary(self) -> bool:
        """True when descriptors are compared by Hamming distance (bits), False for vectors
        compared by Euclidean distance (:data:`BINARY_DESCRIPTORS`)."""
        return self.descriptor in BINARY_DESCRIPTORS

    @property
    def descriptor_scale(self) -> float:
        """Factor that maps the bytes of a vector descriptor to about unit L2 norm: grad36
        ``clip / 255``, SIFT ``1 / 512``; 1 for binary kinds (unused there)."""
        return _vector_scale(self.descriptor, self.clip)

    @property
    def flags(self) -> int:
        """The :attr:`ImageFeatures.flags` that features extracted with these params carry."""
        return FLAG_COLOUR_CONSTANCY if self.colour_constancy else 0

    def matches(self, features: ImageFeatures) -> bool:
        """True when ``features`` were extracted with settings compatible with these (same
        descriptor, working size and colour normalisation), so they can be compared."""
        return (
            features.descriptor == self.descriptor
            and tuple(features.size) == (self.width, self.height)
            and features.flags == self.flags
        )


def _vector_scale(kind: str, clip: float) -> float:
    """See :attr:`FeatureParams.descriptor_scale`."""
    if kind == "grad36":
        return clip / 255.0
    if kind == "sift":
        return 1.0 / SIFT_NORM
    return 1.0


def signature_blocks(params: FeatureParams = FeatureParams()) -> tuple[tuple[str, int], ...]:
    """``(name, length)`` of every signature block, in order (see the module docstring)."""
    summary = params.descriptor_bytes
    tw, th = params.thumb_size
    pw, ph = params.patch_size
    return (
        ("hist", 3 * params.hist_coefficients),
        ("thumb", tw * th * 3),
        ("desc_mean", summary),
        ("desc_var", summary),
        ("patch", pw * ph),
    )


def signature_length(params: FeatureParams = FeatureParams()) -> int:
    """Total signature length S."""
    return sum(n for _, n in signature_blocks(params))


@dataclass(frozen=True, eq=False)
class ImageFeatures:
    """Everything the engine keeps about one image.

    Attributes:
        keypoints: ``(K, 2) float32`` corner (x, y) in pixels at the working size, strongest
            first; ``K <= n_features`` (0 for a blank image).
        descriptors: ``(K, D) uint8``, row k describes keypoint k (D from
            :data:`DESCRIPTOR_BYTES`: 36 grad36, 32 ORB kinds and TEBLID, 128 SIFT, 61 AKAZE,
            64 BRISK).
        signature: ``(S,) float32`` global signature, unit-norm blocks (:func:`signature_blocks`).
        descriptor: which descriptor produced ``descriptors``.
        size: working size ``(width, height)`` in pixels the keypoints refer to.
        flags: how the image was normalised (:data:`FLAG_COLOUR_CONSTANCY`), see
            :meth:`FeatureParams.matches`.
    """

    keypoints: npt.NDArray[np.float32]
    descriptors: npt.NDArray[np.uint8]
    signature: npt.NDArray[np.float32]
    descriptor: DescriptorKind = "grad36"
    size: tuple[int, int] = field(default=(320, 240))
    flags: int = 0

    def __post_init__(self) -> None:
        k = len(self.keypoints)
        if self.keypoints.shape != (k, 2) or self.descriptors.shape[0] != k:
            raise ValueError(
                f"keypoints {self.keypoints.shape} and descriptors {self.descriptors.shape} "
                "must both have one row per corner"
            )
        if self.descriptors.dtype != np.uint8 or self.descriptors.ndim != 2:
            raise ValueError("descriptors must be a (K, D) uint8 array")

    @property
    def n_keypoints(self) -> int:
        return len(self.keypoints)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ImageFeatures):
            return NotImplemented
        return (
            self.descriptor == other.descriptor
            and tuple(self.size) == tuple(other.size)
            and self.flags == other.flags
            and np.array_equal(self.keypoints, other.keypoints)
            and np.array_equal(self.descriptors, other.descriptors)
            and np.array_equal(self.signature, other.signature)
        )

    __hash__ = None  # type: ignore[assignment]

    def to_bytes(self) -> bytes:
        """Compact, versioned binary form (little endian): header, keypoints float32,
        descriptors uint8, signature float32. About 5.5 kB with the defaults."""
        kind = DESCRIPTOR_KINDS.index(self.descriptor)
        d = self.descriptors.shape[1]
        header = _HEADER.pack(
            _MAGIC,
            FORMAT_VERSION,
            kind,
            self.flags,
            self.n_keypoints,
            d,
            len(self.signature),
            int(self.size[0]),
            int(self.size[1]),
        )
        return b"".join(
            (
                header,
                np.ascontiguousarray(self.keypoints, dtype="<f4").tobytes(),
                np.ascontiguousarray(self.descriptors, dtype=np.uint8).tobytes(),
                np.ascontiguousarray(self.signature, dtype="<f4").tobytes(),
            )
        )

    @classmethod
    def from_bytes(cls, data: bytes) -> ImageFeatures:
        """Inverse of :meth:`to_bytes`; ``ValueError`` on a blob of another format or version."""
        if len(data) < _HEADER.size:
            raise ValueError(f"feature blob too short ({len(data)} bytes); re-extract the image")
        magic, version, kind, flags, k, d, s, w, h = _HEADER.unpack_from(data, 0)
        if magic != _MAGIC:
            raise ValueError("not an ImageFeatures blob (bad magic); re-extract the image")
        if version != FORMAT_VERSION:
            raise ValueError(
                f"feature blob version {version}, this code reads {FORMAT_VERSION}; "
                "re-extract the tour's images"
            )
        expected = _HEADER.size + 8 * k + k * d + 4 * s
        if len(data) != expected or kind >= len(DESCRIPTOR_KINDS):
            raise ValueError(f"corrupt feature blob: {len(data)} bytes, expected {expected}")
        off = _HEADER.size
        kp = np.frombuffer(data, dtype="<f4", count=2 * k, offset=off).reshape(k, 2)
        off += 8 * k
        desc = np.frombuffer(data, dtype=np.uint8, count=k * d, offset=off).reshape(k, d)
        off += k * d
        sig = np.frombuffer(data, dtype="<f4", count=s, offset=off)
        return cls(
            keypoints=kp.astype(np.float32),
            descriptors=desc.copy(),
            signature=sig.astype(np.float32),
            descriptor=DESCRIPTOR_KINDS[kind],
            size=(int(w), int(h)),
            flags=int(flags),
        )


# ---------------------------------------------------------------------------------------------
# extraction


def normalise(
    image: npt.NDArray[np.uint8], params: FeatureParams = FeatureParams()
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """Resize to the working size: ``(colour (H, W, 3) BGR uint8, grey (H, W) uint8)``; the
    colour image with (``params.colour_constancy``) :func:`grey_world` normalisation, the grey
    one as the frame came."""
    img = _working_size(image, params)
    # corners, descriptors and the patch block are gain invariant already (normalised
    # gradients, local contrast): they read the frame as it came, without the clipping a gain
    # can cause; only the colour blocks (histogram, thumbnail) read the normalised colours
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if params.colour_constancy:
        img = grey_world(img, params.colour_target, params.colour_percentile)
    return np.ascontiguousarray(img, dtype=np.uint8), np.asarray(grey, np.uint8)


def _working_size(image: npt.NDArray[np.uint8], params: FeatureParams) -> npt.NDArray[np.uint8]:
    """``image`` as ``(H, W, 3)`` BGR uint8 at the working size (grey and BGRA converted)."""
    img: npt.NDArray[Any] = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"expected a uint8 image, got {img.dtype}; convert it first")
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 2 or img.shape[1] < 2:
        raise ValueError(f"expected an (H, W, 3) BGR or (H, W) grey image, got {img.shape}")
    size = (params.width, params.height)
    if img.shape[1] != params.width or img.shape[0] != params.height:
        shrink = img.shape[1] >= params.width and img.shape[0] >= params.height
        interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
        img = cv2.resize(img, size, interpolation=interp)
    return np.asarray(img, np.uint8)


def grey_world(
    image: npt.NDArray[np.uint8], target: float = 160.0, percentile: float = 90.0
) -> npt.NDArray[np.uint8]:
    """Scale each channel of an ``(H, W, 3) uint8`` image so that its ``percentile``-th
    percentile lands on ``target`` grey levels (saturating at 255).

    A change of light that multiplies each channel by a gain scales every percentile by that
    gain, so it cancels. A high percentile rather than the mean keeps the gain from following
    large dark regions in and out of view (black fisheye corners, a dark doorway): on the
    corridor set the tracker's exact recall@1 is 0.910 with it, 0.829 with the mean. A channel
    that is black throughout stays black.
    """
    n = image.shape[0] * image.shape[1]
    gains = np.ones(3, np.float64)
    for c in range(3):
        hist = cv2.calcHist([image], [c], None, [256], [0, 256]).ravel()
        level = int(np.searchsorted(np.cumsum(hist), percentile / 100.0 * n))
        if level > 0:
            gains[c] = target / (level + 0.5)
    out = cv2.transform(image, np.diag(gains).astype(np.float32))
    return np.ascontiguousarray(out, dtype=np.uint8)


#: A rectangle ``(x0, y0, x1, y1)`` in pixels at the working size, ends exclusive.
Region = tuple[int, int, int, int]


def _border_mask(
    params: FeatureParams, border: int, region: Region | None = None
) -> npt.NDArray[np.uint8]:
    """255 where a corner may lie: ``border`` px inside the image and inside ``region``."""
    mask = np.zeros((params.height, params.width), np.uint8)
    x0, y0, x1, y1 = region if region is not None else (0, 0, params.width, params.height)
    x0, y0 = max(x0, border), max(y0, border)
    x1, y1 = min(x1, params.width - border), min(y1, params.height - border)
    if x1 > x0 and y1 > y0:
        mask[y0:y1, x0:x1] = 255
    return mask


def detect_corners(
    grey: npt.NDArray[np.uint8],
    params: FeatureParams = FeatureParams(),
    *,
    region: Region | None = None,
) -> npt.NDArray[np.float32]:
    """Harris corners of a working-size grey image, strongest first: ``(K, 2) float32`` (x, y).

    The detector of the Harris kinds (:data:`HARRIS_DESCRIPTORS`); ``orb`` and ``teblid`` keep
    16 px from the border for their 31 px patch. ``region``: corners only inside this
    rectangle as well (``border`` px inside it when it reaches the image border)."""
    border = params.border if params.descriptor == "grad36" else max(params.border, 16)
    corners = cv2.goodFeaturesToTrack(
        grey,
        maxCorners=params.n_features,
        qualityLevel=params.quality,
        minDistance=params.min_distance,
        mask=_border_mask(params, border, region),
        blockSize=params.harris_block,
        useHarrisDetector=True,
        k=params.harris_k,
    )
    if corners is None:
        return np.zeros((0, 2), np.float32)
    return np.ascontiguousarray(corners.reshape(-1, 2), dtype=np.float32)


def grad36_descriptors(
    grey: npt.NDArray[np.uint8],
    keypoints: npt.NDArray[np.float32],
    params: FeatureParams = FeatureParams(),
) -> npt.NDArray[np.uint8]:
    """The 36-byte gradient descriptor at each keypoint: ``(K, 36) uint8``.

    3x3 cells of ``params.cell`` px around the corner (cell ``(i, j)`` centred ``(j - 1,
    i - 1) * cell`` px from it; an even cell spans ``cell // 2`` px before its centre and
    ``cell // 2 - 1`` after); in each cell the sums of the positive and negative x and y
    gradients (central differences of the image blurred by ``params.blur_sigma``);
    L2-normalised, clipped at ``params.clip``, scaled so the clip maps to 255. Bytes are
    ordered ``[cell row i, cell column j, (+x, -x, +y, -y)]``.

    Only the ``3 * cell + 2`` px square around each corner is read: the cell sums are two
    small matrix products per corner, not filters over the whole image (about 0.3 ms
    instead of 1.8 ms for 100 corners at 320x240). A corner nearer the border than that
    square reads a mirrored image (``BORDER_REFLECT_101``).
    """
    k = len(keypoints)
    if k == 0:
        return np.zeros((0, 36), np.uint8)
    g: npt.NDArray[Any] = grey.astype(np.float32)
    if params.blur_sigma > 0:
        g = cv2.GaussianBlur(g, (0, 0), params.blur_sigma)
    c = params.cell
    side = 3 * c + 2  # the 3x3 cells plus one px each side for the central difference
    before = c + c // 2 + 1  # px of that square above / left of the corner
    xs = np.rint(keypoints[:, 0]).astype(np.intp) - before
    ys = np.rint(keypoints[:, 1]).astype(np.intp) - before
    h, w = g.shape
    if xs.min() < 0 or ys.min() < 0 or xs.max() + side > w or ys.max() + side > h:
        g = cv2.copyMakeBorder(g, side, side, side, side, cv2.BORDER_REFLECT_101)
        xs, ys = xs + side, ys + side
    patches = np.lib.stride_tricks.sliding_window_view(g, (side, side))[ys, xs]  # (K, s, s)
    maps = np.empty((k, 4, 3 * c, 3 * c), np.float32)  # +x, -x, +y, -y gradients
    for ch, (ahead, behind) in enumerate(
        (
            (patches[:, 1:-1, 2:], patches[:, 1:-1, :-2]),
            (patches[:, 2:, 1:-1], patches[:, :-2, 1:-1]),
        )
    ):
        pos, neg = maps[:, 2 * ch], maps[:, 2 * ch + 1]
        np.subtract(ahead, behind, out=neg)  # the gradient, for now
        np.maximum(neg, 0.0, out=pos)
        np.subtract(pos, neg, out=neg)  # max(d, 0) - d = max(-d, 0)
    cells = _cell_sums(c)
    sums = cells.T @ maps @ cells  # (K, 4, 3, 3): [k, channel, cell row, cell column]
    desc = sums.transpose(0, 2, 3, 1).reshape(k, 36)
    norm = np.linalg.norm(desc, axis=1, keepdims=True)
    desc = desc / np.maximum(norm, 1e-6)
    desc = np.minimum(desc, params.clip)
    norm = np.linalg.norm(desc, axis=1, keepdims=True)
    desc = desc / np.maximum(norm, 1e-6)
    return np.clip(np.rint(desc * (255.0 / params.clip)), 0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=8)
def _cell_sums(cell: int) -> npt.NDArray[np.float32]:
    """``(3 cell, 3) float32`` 0/1 matrix: ``m @ it`` sums the columns of ``m`` per cell."""
    m = np.repeat(np.eye(3, dtype=np.float32), cell, axis=0)
    m.flags.writeable = False  # shared by every call
    return m


def _contrib(name: str) -> Any:
    """The OpenCV class ``name`` (``AKAZE``, ``BRISK``, ``TEBLID``): in ``cv2.xfeatures2d``
    (OpenCV 5 with contrib) or in ``cv2`` (4.x); a helpful error without the contrib build."""
    for module in (getattr(cv2, "xfeatures2d", None), cv2):
        cls = getattr(module, name, None)
        if cls is not None and hasattr(cls, "create"):
            return cls
    raise RuntimeError(
        f"OpenCV {cv2.__version__} has no {name}: install opencv-contrib-python-headless "
        "(pip uninstall opencv-python-headless first: the two must not be installed together)"
    )


# Feature2D objects that are dear to create (BRISK builds its sampling pattern: ~20 ms), one
# per thread so that concurrent extractions share no state
_CACHED = threading.local()


def _feature2d(kind: DescriptorKind, n_features: int) -> cv2.Feature2D:
    """The OpenCV object that detects and / or describes ``kind`` (not ``grad36``)."""
    if kind == "orb":  # descriptor only, at Harris corners (16 px from the border)
        return cv2.ORB.create(edgeThreshold=16, patchSize=31)
    if kind == "orb_fast":
        return cv2.ORB.create(nfeatures=n_features)
    if kind == "sift":
        return cv2.SIFT.create(nfeatures=n_features)
    if kind == "akaze":
        return _contrib("AKAZE").create()
    if kind == "akaze_upright":
        akaze = _contrib("AKAZE")
        upright = getattr(getattr(cv2, "xfeatures2d", cv2), "AKAZE_DESCRIPTOR_MLDB_UPRIGHT", 4)
        return akaze.create(descriptor_type=upright)
    if kind == "teblid":  # 256 bits; scale factor 1 for keypoints of size 31 (as ORB's)
        teblid = _contrib("TEBLID")
        bits = getattr(getattr(cv2, "xfeatures2d", cv2), "TEBLID_SIZE_256_BITS", 102)
        return teblid.create(1.0, bits)
    if kind == "brisk":
        cached: cv2.Feature2D | None = getattr(_CACHED, "brisk", None)
        if cached is None:
            cached = _contrib("BRISK").create()
            _CACHED.brisk = cached
        return cached
    raise ValueError(f"{kind!r} is computed by this module, not by an OpenCV Feature2D")


def harris_descriptors(
    grey: npt.NDArray[np.uint8],
    keypoints: npt.NDArray[np.float32],
    kind: DescriptorKind = "orb",
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """An OpenCV binary descriptor (``orb``: upright ORB/rBRIEF; ``teblid``: upright 256-bit
    TEBLID) at the given Harris corners of a working-size grey image, each described as a
    31 px keypoint at angle 0.

    Returns the corners kept (OpenCV may drop those too close to the border), ``(K, 2)
    float32`` (x, y) px, and their descriptors ``(K, D) uint8``.
    """
    d = DESCRIPTOR_BYTES[kind]
    if len(keypoints) == 0:
        return np.zeros((0, 2), np.float32), np.zeros((0, d), np.uint8)
    kps = [cv2.KeyPoint(float(x), float(y), 31.0) for x, y in keypoints]
    kept, desc = _feature2d(kind, len(kps)).compute(grey, kps)
    if desc is None or len(kept) == 0:
        return np.zeros((0, 2), np.float32), np.zeros((0, d), np.uint8)
    pts = np.array([kp.pt for kp in kept], np.float32).reshape(-1, 2)
    return pts, np.ascontiguousarray(desc, dtype=np.uint8).reshape(-1, d)


def orb_descriptors(
    grey: npt.NDArray[np.uint8], keypoints: npt.NDArray[np.float32]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """Upright ORB (rBRIEF pattern, no orientation) at the given corners:
    :func:`harris_descriptors` with ``kind="orb"``; ``(K, 32) uint8``."""
    return harris_descriptors(grey, keypoints, "orb")


def opencv_features(
    grey: npt.NDArray[np.uint8], params: FeatureParams = FeatureParams()
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """Keypoints and descriptors of the kinds with their own OpenCV detector (``orb_fast``,
    ``sift``, ``akaze``, ``akaze_upright``, ``brisk``) on a working-size grey image.

    Returns ``(K, 2) float32`` (x, y) in pixels at the working size and ``(K, D) uint8``,
    strongest detector response first, ``K <= params.n_features`` (SIFT may return a keypoint
    twice with two orientations; each counts). AKAZE and BRISK have no keypoint budget of
    their own: they detect all they find and the strongest are kept. Detector objects are
    created per call (well under a microsecond), BRISK's once per thread, so concurrent calls
    share no state.
    """
    d = params.descriptor_bytes
    if params.descriptor in HARRIS_DESCRIPTORS:
        raise ValueError(f"{params.descriptor!r} uses Harris corners: call detect_corners")
    detector = _feature2d(params.descriptor, params.n_features)
    kps, desc = detector.detectAndCompute(grey, None)
    if desc is None or len(kps) == 0:
        return np.zeros((0, 2), np.float32), np.zeros((0, d), np.uint8)
    response = np.fromiter((k.response for k in kps), np.float32, count=len(kps))
    order = np.argsort(-response, kind="stable")[: params.n_features]
    pts = np.asarray(cv2.KeyPoint.convert(kps), np.float32).reshape(-1, 2)[order]
    # SIFT: OpenCV's float values are already whole numbers in [0, 255] (see the module doc)
    values = np.clip(np.rint(np.asarray(desc)[order]), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(pts), np.ascontiguousarray(values.reshape(-1, d))


def _unit(v: npt.NDArray[np.floating]) -> npt.NDArray[np.float32]:
    v = np.asarray(v, np.float32).ravel()
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 else np.zeros_like(v)


def _descriptor_values(desc: npt.NDArray[np.uint8], kind: str) -> npt.NDArray[np.float32]:
    if kind in BINARY_DESCRIPTORS:
        return np.bitwise_count(desc).astype(np.float32)  # per-byte bit counts, 0..8
    return desc.astype(np.float32)


def compute_signature(
    colour: npt.NDArray[np.uint8],
    grey: npt.NDArray[np.uint8],
    descriptors: npt.NDArray[np.uint8],
    params: FeatureParams = FeatureParams(),
) -> npt.NDArray[np.float32]:
    """The global signature of a working-size image: ``(S,) float32``, unit-norm blocks."""
    ycrcb = cv2.cvtColor(colour, cv2.COLOR_BGR2YCrCb)
    hists = []
    for ch in (0, 2, 1):  # Y, Cb, Cr
        hst = cv2.calcHist([ycrcb], [ch], None, [params.hist_bins], [0, 256]).ravel()
        root = np.sqrt(hst / max(float(hst.sum()), 1.0)).astype(np.float32)
        hists.append(cv2.dct(root.reshape(-1, 1)).ravel()[: params.hist_coefficients])
    hist = _unit(np.concatenate(hists))

    thumb = cv2.resize(colour, params.thumb_size, interpolation=cv2.INTER_AREA).astype(np.float32)
    thumb = _unit(thumb - thumb.mean())

    summary = params.descriptor_bytes
    if len(descriptors):
        vals = _descriptor_values(descriptors, params.descriptor)
        d_mean = _unit(vals.mean(axis=0))
        d_var = _unit(vals.var(axis=0))
    else:
        d_mean = d_var = np.zeros(summary, np.float32)

    small = cv2.resize(grey, params.patch_size, interpolation=cv2.INTER_AREA).astype(np.float32)
    win = (params.patch_window, params.patch_window)
    mean = cv2.blur(small, win, borderType=cv2.BORDER_REFLECT)
    sq = cv2.blur(small * small, win, borderType=cv2.BORDER_REFLECT)
    std = np.sqrt(np.maximum(sq - mean * mean, 0.0))
    patch = _unit((small - mean) / (std + 2.0))

    return np.concatenate([hist, thumb, d_mean, d_var, patch]).astype(np.float32)


def extract(image: npt.NDArray[np.uint8], params: FeatureParams = FeatureParams()) -> ImageFeatures:
    """Features of one frame.

    Args:
        image: ``(H, W, 3) uint8`` BGR or ``(H, W) uint8`` grey, any size (resized to the working
            size ``params.width x params.height``).
        params: extraction parameters.

    Returns:
        :class:`ImageFeatures` with at most ``params.n_features`` corners, strongest first.
    """
    colour, grey = normalise(image, params)
    corners, desc = _corners_and_descriptors(grey, params)
    signature = compute_signature(colour, grey, desc, params)
    return ImageFeatures(
        keypoints=corners,
        descriptors=desc,
        signature=signature,
        descriptor=params.descriptor,
        size=(params.width, params.height),
        flags=params.flags,
    )


def extract_corners(
    image: npt.NDArray[np.uint8],
    params: FeatureParams = FeatureParams(),
    *,
    region: Region | None = None,
) -> ImageFeatures:
    """The corners and descriptors of one frame, without the global signature: what matching
    and homing (:mod:`server.vision.homing`) read, for about 60 % of the cost of
    :func:`extract`. Keypoints and descriptors equal those :func:`extract` gives; the
    ``signature`` is empty, so these features cannot be added to or queried in an index.

    ``region`` ``(x0, y0, x1, y1)``, px at the working size: only corners inside it (the
    Harris kinds pick their ``n_features`` strongest there; the others drop the rest)."""
    grey = cv2.cvtColor(_working_size(image, params), cv2.COLOR_BGR2GRAY)
    corners, desc = _corners_and_descriptors(np.asarray(grey, np.uint8), params, region)
    return ImageFeatures(
        keypoints=corners,
        descriptors=desc,
        signature=np.zeros(0, np.float32),
        descriptor=params.descriptor,
        size=(params.width, params.height),
        flags=params.flags,
    )


def _corners_and_descriptors(
    grey: npt.NDArray[np.uint8], params: FeatureParams, region: Region | None = None
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    if params.descriptor not in HARRIS_DESCRIPTORS:
        pts, desc = opencv_features(grey, params)
        if region is None:
            return pts, desc
        x0, y0, x1, y1 = region
        inside = (pts[:, 0] >= x0) & (pts[:, 0] < x1) & (pts[:, 1] >= y0) & (pts[:, 1] < y1)
        return np.ascontiguousarray(pts[inside]), np.ascontiguousarray(desc[inside])
    corners = detect_corners(grey, params, region=region)
    if params.descriptor == "grad36":
        return corners, grad36_descriptors(grey, corners, params)
    return harris_descriptors(grey, corners, params.descriptor)


def descriptor_distances(
    a: npt.NDArray[np.uint8],
    b: npt.NDArray[np.uint8],
    kind: DescriptorKind = "grad36",
    params: FeatureParams = FeatureParams(),
) -> npt.NDArray[np.float32]:
    """Pairwise descriptor distances ``(Ka, Kb) float32``, normalised to about [0, 1].

    Vector kinds: Euclidean distance of the descriptors scaled to nominal unit norm
    (:attr:`FeatureParams.descriptor_scale`: grad36 ``clip / 255``, SIFT ``1 / 512``); binary
    kinds (:data:`BINARY_DESCRIPTORS`): Hamming distance divided by the number of bits.
    ``params`` only supplies the grad36 clip; ``kind`` says which descriptor ``a`` and ``b`` are.
    """
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)), np.float32)
    if kind not in BINARY_DESCRIPTORS:
        scale = np.float32(_vector_scale(kind, params.clip))
        af = a.astype(np.float32) * scale
        bf = b.astype(np.float32) * scale
        sq = (af * af).sum(1)[:, None] + (bf * bf).sum(1)[None, :] - 2.0 * (af @ bf.T)
        return np.sqrt(np.maximum(sq, 0.0)).astype(np.float32)
    bits = 8 * a.shape[1]
    xor = a[:, None, :] ^ b[None, :, :]
    return (np.bitwise_count(xor).sum(axis=2) / bits).astype(np.float32)
