"""Training feeds over BOP datasets (torch imported only when a sample is built or a batch collated).

| module | owns |
|---|---|
| :mod:`~simtest.data.feed` | what every map-style feed shares: one entry per image, per-sample seeds, crops, ``collate`` |
| :mod:`~simtest.data.labelled` | :class:`PoseDataset`: labelled samples (masks, poses, keypoints), symmetry canonicalisation |
| :mod:`~simtest.data.augment` | seeded on-the-fly corruptions for training (:func:`augmentation`) |
| :mod:`~simtest.data.mixing` | unlabelled target-domain images, seeded mixtures of labelled and unlabelled feeds, mixtures of several labelled datasets (:func:`labelled_mixture`) |
| :mod:`~simtest.data.dense` | the dense ground-truth channels of a sample (instances, coords, normals, flow) |
| :mod:`~simtest.data.pointclouds` | per-frame, per-object point clouds of a sequence (:class:`PointCloudSequence`) |

Everything documented as ``simtest.data.NAME`` is importable from here.
"""

from simtest.data.dense import DENSE_CHANNELS, load_channels
from simtest.data.augment import (AUGMENTATIONS, TRAIN_WEATHER, BackgroundSwap, ColorJitter, Compose, Corrupt, ObjectLight,
                                  RandomCorrupt, augmentation)
from simtest.data.feed import (ImageEntry, ImageFeed, check_feed_options, check_seed, collate, crop_intrinsics,
                               crop_window, sample_rng)
from simtest.data.labelled import KEYPOINT_TYPES, PoseDataset, canonical_symmetry, project_points
from simtest.data.mixing import MixedDataset, UnlabelledDataset, collate_mixed, labelled_mixture, parse_weights
from simtest.data.pointclouds import ObjectPoints, PointCloudSequence
from simtest.io.dense import nocs_from_coords

__all__ = [
    "PoseDataset", "Corrupt", "RandomCorrupt", "ColorJitter", "ObjectLight", "BackgroundSwap", "Compose", "collate", "sample_rng", "project_points",
    "canonical_symmetry", "KEYPOINT_TYPES", "TRAIN_WEATHER", "augmentation", "AUGMENTATIONS",
    "PointCloudSequence", "ObjectPoints", "ImageFeed", "ImageEntry", "check_feed_options", "check_seed",
    "crop_window", "crop_intrinsics", "UnlabelledDataset", "MixedDataset", "collate_mixed", "DENSE_CHANNELS",
    "load_channels", "nocs_from_coords", "labelled_mixture", "parse_weights",
]
