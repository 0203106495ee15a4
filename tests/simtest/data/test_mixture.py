"""Mixtures of labelled datasets: stated proportions, seeded order, the training feed of several datasets."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.data import MixedDataset, PoseDataset, labelled_mixture, parse_weights
from simtest.errors import ConfigError


def test_the_mixture_draws_the_stated_proportions_in_a_seeded_order(small_dataset):
    a = PoseDataset(small_dataset, seed=0)
    b = PoseDataset(small_dataset, seed=1, max_images=2)
    mix = MixedDataset([a, b], ratio=(0.7, 0.3), length=10000, seed=5)
    source, index = mix.order()
    share = np.bincount(source, minlength=2) / len(source)
    assert abs(share[0] - 0.7) < 0.02 and abs(share[1] - 0.3) < 0.02, share
    assert index[source == 1].max() < len(b) and index[source == 0].max() < len(a)
    # same seed, same order; another seed or epoch, another order
    again = MixedDataset([a, b], ratio=(0.7, 0.3), length=10000, seed=5).order()
    assert np.array_equal(again[0], source) and np.array_equal(again[1], index)
    other = MixedDataset([a, b], ratio=(0.7, 0.3), length=10000, seed=6).order()
    assert not np.array_equal(other[0], source)
    mix.set_epoch(1)
    assert not np.array_equal(mix.order()[0], source)
    # the proportions hold in every window a loader would draw, not only in total
    first = source[:2000]
    assert abs(first.mean() - 0.3) < 0.04


def test_labelled_mixture_of_several_datasets(small_dataset):
    single = labelled_mixture([str(small_dataset)], seed=3)
    assert isinstance(single, PoseDataset)
    mix = labelled_mixture([str(small_dataset), str(small_dataset)], weights=(0.25, 0.75), seed=3, max_images=4)
    assert isinstance(mix, MixedDataset) and mix.ratio == (0.25, 0.75)
    assert [d.seed for d in mix.datasets] == [3, 4]  # the two datasets corrupt their images differently
    assert len(mix) == 8 and mix.counts() == [2, 6]
    source, index = mix.order()
    for i in range(3):
        s = mix[i]
        assert s["source"] == source[i] and s["index"] == index[i] and s["labelled"]
    default = labelled_mixture([str(small_dataset), str(small_dataset)], max_images=4)
    assert default.ratio == (0.5, 0.5)  # proportional to the datasets' sizes
    with pytest.raises(ConfigError, match="2 mixture weights given for 1 datasets"):
        labelled_mixture([str(small_dataset)], weights=(0.5, 0.5))


def test_parse_weights():
    assert parse_weights("0.7,0.3", 2) == (0.7, 0.3)
    assert parse_weights(None, 3) is None
    for bad in ("0.7", "a,b", "-1,2", "0,0"):
        with pytest.raises(ConfigError, match="--data-weights must be 2"):
            parse_weights(bad, 2)
