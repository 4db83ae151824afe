"""TensorBoard logs of a training run, beside its CSV: ``OUT/tensorboard/episodes`` holds each finished episode's
return, final completion and MB at the env steps it ended (the same x axis in every action form, so runs of
different forms and seeds overlay), ``OUT/tensorboard/ppo`` PPO's own figures (losses, entropy, explained
variance, KL, clip fraction) at SB3's step count (agent transitions). ``tensorboard --logdir runs/`` shows
every run under it.
"""

from __future__ import annotations

from pathlib import Path


def check_tensorboard() -> None:
    """ImportError naming the package when TensorBoard's writer is missing."""
    try:
        from torch.utils.tensorboard import SummaryWriter  # noqa: F401, PLC0415
    except ImportError:
        raise ImportError("TensorBoard logs need the tensorboard package: pip install 'openmulti[train]' (make setup "
                          "installs it), or train with --train.tensorboard False") from None


class TrainingBoard:
    """Writes episodes as they finish (``episodes(rows)`` takes the whole log and writes the new rows) and points
    SB3's logger at ``ppo``. ``written`` rows of a resumed run are not written again."""

    def __init__(self, folder: Path, model, written: int = 0):
        check_tensorboard()
        from stable_baselines3.common.logger import configure  # noqa: PLC0415
        from torch.utils.tensorboard import SummaryWriter  # noqa: PLC0415

        folder = Path(folder)
        self.writer = SummaryWriter(str(folder / "episodes"))
        self.written = int(written)
        model.set_logger(configure(str(folder / "ppo"), ["tensorboard"]))

    def episodes(self, rows: list[dict]) -> None:
        for row in rows[self.written:]:
            step = int(row["env_steps"])
            self.writer.add_scalar("episode/return", row["return"], step)
            self.writer.add_scalar("episode/completion_pct", row["completion"], step)
            self.writer.add_scalar("episode/mb_team", row["mb"], step)
        if len(rows) > self.written:
            self.written = len(rows)
            self.writer.flush()

    def close(self) -> None:
        self.writer.close()
