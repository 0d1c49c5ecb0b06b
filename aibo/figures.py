"""PNG figures of a learning run, like the paper's Fig. 2 and Fig. 3 (matplotlib, headless)."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from aibo_core.atomic import atomic_write  # noqa: E402
from learners.model.sensor import SensorModel  # noqa: E402


def save_png(fig, path: str | Path, dpi: int = 110) -> None:
    """``fig`` written to ``path`` as a PNG, atomically (a reader never sees half a file), and closed."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    atomic_write(path, lambda f: f.write(buf.getvalue()))


def sensor_models(path, d_range: tuple[float, float], curves: dict[str, SensorModel | np.ndarray],
                  points: tuple[np.ndarray, np.ndarray] | None = None, title: str = "Sensor model") -> None:
    """Fig. 2: height (px) against distance (mm) for several models; arrays are true heights on the grid."""
    d = np.linspace(d_range[0], d_range[1], 300)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    if points is not None:
        ax.scatter(points[0], points[1], s=2, c="0.75", label="sightings (true distance)", rasterized=True)
    styles = {"start": ("tab:red", "--"), "learned": ("tab:blue", "-"), "true": ("k", ":"), "oracle": ("tab:green", "-.")}
    for name, model in curves.items():
        y = model.mean(d) if isinstance(model, SensorModel) else np.asarray(model)
        color, ls = styles.get(name.split()[0], (None, "-"))
        ax.plot(d, y, color=color, ls=ls, lw=2, label=name)
    ax.set_xlabel("distance to beacon (mm)")
    ax.set_ylabel("beacon height (px)")
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    save_png(fig, path)


def loglik_curve(path, loglik: Sequence[float], best_iteration: int | None = None, title: str = "EM log-likelihood") -> None:
    """Fig. 3a: log p(O | lambda) per EM iteration."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    it = np.arange(1, len(loglik) + 1)
    ax.plot(it, loglik, lw=1.5)
    if best_iteration is not None:
        ax.axvline(best_iteration, color="tab:green", ls="--", label=f"best (iteration {best_iteration})")
        ax.legend()
    lo = np.percentile(loglik, 5) if len(loglik) > 10 else min(loglik)
    ax.set_ylim(lo - 0.05 * abs(max(loglik) - lo) - 1, max(loglik) + 0.05 * abs(max(loglik) - lo) + 1)
    ax.set_xlabel("EM iteration")
    ax.set_ylabel("log-likelihood")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    save_png(fig, path)


def velocity_error_curves(path, errors: dict[str, Sequence[float]], oracle: dict[str, float] | None = None,
                          title: str = "Velocity RMS error per iteration") -> None:
    """Fig. 3b: RMS velocity error (fraction of range) per iteration for vx, vy, vtheta."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    colors = {"vx": "tab:blue", "vy": "tab:orange", "vtheta": "tab:green"}
    for name, series in errors.items():
        ax.plot(np.arange(1, len(series) + 1), 100 * np.asarray(series), color=colors.get(name), label=f"EM {name}")
        if oracle and name in oracle:
            ax.axhline(100 * oracle[name], color=colors.get(name), ls=":", lw=1, label=f"oracle {name}")
    ax.set_yscale("log")
    ax.set_xlabel("EM iteration")
    ax.set_ylabel("RMS error (% of velocity range)")
    ax.set_title(title)
    ax.legend(ncol=2, fontsize=8)
    ax.grid(alpha=0.3, which="both")
    save_png(fig, path)
