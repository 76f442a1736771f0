"""Small real-image cases from the shared data folder, with expected results."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from server.vision import TourIndex, extract


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path))
    assert img is not None, path
    return img


def test_corridor_queries_find_their_reference(shared_data: Path) -> None:
    refs = sorted((shared_data / "corridor" / "ref").glob("*.jpg"))
    truth = json.loads((shared_data / "corridor" / "ground_truth.json").read_text())
    idx = TourIndex()
    idx.add([extract(_read(p)) for p in refs], np.arange(len(refs)))
    queries = [5, 20, 35, 50, 65, 80, 95]
    hits = 0
    for q in queries:
        sim = idx.query(extract(_read(shared_data / "corridor" / "query" / f"{q:07d}.jpg")))
        hits += int(np.argmax(sim.image)) in truth[str(q)]
    assert hits >= 6, f"only {hits} of {len(queries)} corridor queries found their reference"


def test_ukbench_object_group_comes_first(shared_data: Path) -> None:
    paths = sorted((shared_data / "ukbench").glob("*.jpg"))
    feats = [extract(_read(p)) for p in paths]
    idx = TourIndex()
    idx.add(feats[1:], np.arange(1, len(feats)) // 4)  # image 0 is the query; groups of 4
    sim = idx.query(feats[0])
    assert int(np.argmax(sim.state)) == 0
    assert int(np.argmax(sim.image)) + 1 in (1, 2, 3)
