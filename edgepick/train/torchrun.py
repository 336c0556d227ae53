"""The torchrun environment of a training process, read and checked. No torch import: the CLI
checks it, and the rest of its input, before it loads torch."""

from __future__ import annotations

import os

from edgepick.errors import ConfigError


def _env_int(name: str, default: int) -> int:
    """The whole number in environment variable NAME, DEFAULT when it is not set."""
    text = os.environ.get(name)
    if text is None:
        return default
    try:
        return int(text)
    except ValueError:
        raise ConfigError(f"{name}={text!r} is not a whole number (torchrun sets it for each process)") from None


def dist_env() -> tuple[int, int, int]:
    """(rank, world size, local rank) under torchrun; (0, 1, 0) otherwise. The variables are
    checked: a WORLD_SIZE above 1 needs the rest of what torchrun sets (RANK, MASTER_ADDR,
    MASTER_PORT), or the process group would wait for peers that never come."""
    world = _env_int("WORLD_SIZE", 1)
    if world < 1:
        raise ConfigError(f"WORLD_SIZE={world}: must be 1 or more")
    if world == 1:
        return 0, 1, 0
    missing = [v for v in ("RANK", "MASTER_ADDR", "MASTER_PORT") if not os.environ.get(v)]
    if missing:
        raise ConfigError(f"WORLD_SIZE={world} but {', '.join(missing)} not set: start multi-process training with "
                          "torchrun --nproc_per_node N -m edgepick train ...")
    rank, local_rank = _env_int("RANK", 0), _env_int("LOCAL_RANK", 0)
    if not 0 <= rank < world or local_rank < 0:
        raise ConfigError(f"RANK={rank} (LOCAL_RANK={local_rank}) does not fit WORLD_SIZE={world}")
    return rank, world, local_rank
