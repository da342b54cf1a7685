"""Prints every scalar of the TensorBoard event files under a folder as JSON,
{tag: [[step, value], ...]}, read by TensorBoard's own EventAccumulator.

Usage: tensorboard_scalars.py RUN_DIR/tensorboard
"""

import json
import sys

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator


def main(folder):
    acc = EventAccumulator(folder, size_guidance={"scalars": 0})
    acc.Reload()
    out = {}
    for tag in acc.Tags()["scalars"]:
        out[tag] = [[e.step, e.value] for e in acc.Scalars(tag)]
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
