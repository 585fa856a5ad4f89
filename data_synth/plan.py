"""From a dataset spec to the list of samples to render, each with its exact parameters
and its own seed.

Seeds: all randomness derives from the spec's integer ``seed`` through
`numpy.random.SeedSequence` spawn keys, so that any one sample can be produced on
its own (a resumed run gives the same bytes as an uninterrupted one):

- the random parameter draws of group g use ``SeedSequence(seed, spawn_key=(0, g))``;
- the sensor noise of sample j of group g uses ``SeedSequence(seed, spawn_key=(1, g, j))``
  (recorded in the sample's sidecar).

Order: groups in spec order; within a group, parameter sets in sampling order, each
rendered in every scene of the group before the next set. Sample j of group ``NAME`` has
the id ``NAME-jjjj`` (zero-padded to at least 4 digits).
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from .params import MODELS, Value, expand_grid, expand_random
from .spec import DatasetSpec, Group, SceneRef

#: First spawn-key element of the parameter draws and of the sensor noise.
PARAMETER_STREAM, NOISE_STREAM = 0, 1


@dataclass(frozen=True)
class SamplePlan:
    """One sample to render: ``parameters`` are exactly what the material is built from."""

    id: str
    group: Group
    group_index: int
    index: int
    scene: SceneRef
    parameters: dict[str, Value]
    spawn_key: tuple[int, ...]

    @property
    def model(self) -> str:
        return self.group.model


def parameter_sets(spec: DatasetSpec, group_index: int) -> list[dict[str, Value]]:
    """The parameter sets of one group (grid order, or extremes then draws)."""
    group = spec.groups[group_index]
    model = MODELS[group.model]
    if group.sampling == "grid":
        return expand_grid(model, group.axes)
    rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(PARAMETER_STREAM, group_index)))
    return expand_random(model, group.axes, group.count, group.extremes, rng)


def plan_samples(spec: DatasetSpec) -> list[SamplePlan]:
    """Every sample of the dataset, in order."""
    samples: list[SamplePlan] = []
    for g, group in enumerate(spec.groups):
        combos = list(itertools.product(parameter_sets(spec, g), group.scenes))
        digits = max(4, len(str(len(combos) - 1)))
        for j, (parameters, scene) in enumerate(combos):
            samples.append(
                SamplePlan(f"{group.name}-{j:0{digits}d}", group, g, j, scene, parameters, (NOISE_STREAM, g, j))
            )
    return samples


def noise_rng(spec: DatasetSpec, sample: SamplePlan) -> np.random.Generator:
    """The generator of one sample's sensor noise."""
    return np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=sample.spawn_key))


def describe(spec: DatasetSpec, sample: SamplePlan) -> dict[str, Any]:
    """Everything that determines a sample's files (the sidecar minus its file list)."""
    group = sample.group
    return {
        "id": sample.id,
        "group": group.name,
        "index": sample.index,
        "model": group.model,
        "parameters": sample.parameters,
        "scene": {"name": sample.scene.name, "file": sample.scene.file, "definition": sample.scene.definition},
        "sensor": group.sensor.to_dict(),
        "formats": list(group.formats),
        "seed": {"entropy": spec.seed, "spawn_key": list(sample.spawn_key)},
    }


def plan_digest(spec: DatasetSpec, samples: list[SamplePlan]) -> str:
    """SHA-256 of every sample's description: equal digests mean the same dataset."""
    text = json.dumps([describe(spec, s) for s in samples], sort_keys=True, allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
