"""The image-similarity engine: the observation model of the belief tracker (001 section 5).

Pure core: this package imports NumPy, OpenCV and the standard library only.

Pipeline, one module per step:

1. :mod:`server.vision.features` - normalise a frame to the working size, Harris corners with a
   compact descriptor, and the global signature (YCbCr histogram, thumbnail, descriptor summary,
   patch-normalised thumbnail). ``ImageFeatures.to_bytes`` is what storage persists.
2. :mod:`server.vision.index` - the per-tour index (contiguous arrays, incremental ``add``), the
   two-pass query (weighted signature distance to every image, then local features and an optional
   RANSAC check on the candidates).
   On tours of ``EngineParams.index_min_images`` images or more, the candidates come from
   :mod:`server.vision.inverted` (signature lists and visual words) in sub-linear time.
3. :mod:`server.vision.learning` - the signature weights learned per tour, on the tour's images
   and on copies of them under changed light (:mod:`server.vision.augment`).
4. :mod:`server.vision.homing` - horizontal offset between the current frame and a target image,
   for visual homing along an edge (001 section 7.2), and the scale between them (how far short
   of or past the target's viewpoint the robot stands) for the last metre onto a place.
"""

from server.vision.features import FeatureParams, ImageFeatures, extract
from server.vision.homing import (
    HomingParams,
    HomingResult,
    ScaleParams,
    ScaleResult,
    homing_offset,
    homing_scale,
    match_features,
)
from server.vision.index import (
    EngineParams,
    IndexParams,
    Similarity,
    TourIndex,
    default_weights,
)
from server.vision.learning import LearnParams, learn_tour_weights, learn_weights

__all__ = [
    "EngineParams",
    "FeatureParams",
    "HomingParams",
    "HomingResult",
    "ImageFeatures",
    "IndexParams",
    "LearnParams",
    "ScaleParams",
    "ScaleResult",
    "Similarity",
    "TourIndex",
    "default_weights",
    "extract",
    "homing_offset",
    "homing_scale",
    "learn_tour_weights",
    "learn_weights",
    "match_features",
]
