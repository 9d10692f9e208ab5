"""The training-curve figure beside each model card: Ultralytics' per-epoch losses and validation mAP."""

from __future__ import annotations

from pathlib import Path


def plot_training_curves(results_csv: Path, out_png: Path) -> Path | None:
    """Plot Ultralytics' per-epoch losses and validation mAP (matplotlib, Agg)."""
    if not results_csv.is_file():
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    with results_csv.open() as f:
        header = [h.strip() for h in f.readline().split(",")]
    data = np.loadtxt(results_csv, delimiter=",", skiprows=1, ndmin=2)
    col = {h: data[:, i] for i, h in enumerate(header)}
    fig, (ax_loss, ax_map) = plt.subplots(1, 2, figsize=(10, 4))
    for key in ("train/box_loss", "train/cls_loss", "train/dfl_loss", "val/box_loss"):
        if key in col:
            ax_loss.plot(col["epoch"], col[key], label=key)
    ax_loss.set(xlabel="epoch", ylabel="loss", title="losses")
    ax_loss.legend()
    for key in ("metrics/mAP50(B)", "metrics/mAP50-95(B)"):
        if key in col:
            ax_map.plot(col["epoch"], col[key], label=key.removeprefix("metrics/"))
    ax_map.set(xlabel="epoch", ylabel="mAP (validation split)", title="validation mAP", ylim=(0, 1))
    ax_map.legend()
    fig.tight_layout()
    fig.savefig(out_png, dpi=100)
    plt.close(fig)
    return out_png
