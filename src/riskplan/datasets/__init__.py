"""Point-cloud data sets by the MDN paper's protocol (section III) and their HDF5 storage.

>>> from riskplan.datasets import generate_dataset, load_dataset
>>> path = generate_dataset("paper", "small", "small_train.h5", split="train", seed=0)  # doctest: +SKIP
>>> ds = load_dataset(path)                                                            # doctest: +SKIP
>>> ds.points.shape   # (C, S, P, 3)                                                    # doctest: +SKIP
"""

from riskplan.datasets.generate import (
    generate_dataset,
    generate_splits,
    simulate_target,
    split_paths,
)
from riskplan.datasets.protocol import (
    PRESETS,
    Protocol,
    get_protocol,
    grid,
    random_starts,
    straight_path,
    target_configurations,
)
from riskplan.datasets.storage import FORMAT, FORMAT_VERSION, Dataset, load_dataset
from riskplan.datasets.summary import summarize

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "PRESETS",
    "Dataset",
    "Protocol",
    "generate_dataset",
    "generate_splits",
    "get_protocol",
    "grid",
    "load_dataset",
    "random_starts",
    "simulate_target",
    "split_paths",
    "straight_path",
    "summarize",
    "target_configurations",
]
