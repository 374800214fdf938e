"""Figures of a solved trajectory (matplotlib, written to files; no screen needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jtraj.result import Result

__all__ = ["plot_result", "plot_convergence"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _rpy_unwrapped(xyz_wxyz: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw accumulated from the relative rotations (so a flip reads as 2 pi)."""
    from jtraj import lie
    from jtraj.lie import SO3

    R = SO3(xyz_wxyz[:, 3:7])
    steps = np.asarray(lie.log(SO3(R.wxyz[1:]) @ SO3(R.wxyz[:-1]).inverse()))
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])


def plot_result(result: Result, path: str | Path) -> Path:
    """Base position, base rotation (world-axis angles, unwrapped), contact forces and joint
    torques against time, with contact phases shaded."""
    plt = _pyplot()
    t = result.trajectory
    if t is None:
        raise ValueError("the result has no trajectory (solve(..., keep_trajectory=True))")
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5), sharex=True)
    touching = t.in_contact.any(axis=1)
    for ax in axes.ravel():
        for k in np.flatnonzero(~touching):
            ax.axvspan(t.t[k] - 0.5 * (t.t[1] - t.t[0]), t.t[k] + 0.5 * (t.t[1] - t.t[0]), color="0.92", lw=0)
    ax = axes[0, 0]
    for i, name in enumerate("xyz"):
        ax.plot(t.t, t.base_xyz_wxyz[:, i], label=name)
    ax.set_ylabel("base position (m)")
    ax.legend(fontsize=8)
    ax = axes[0, 1]
    angles = _rpy_unwrapped(t.base_xyz_wxyz)
    for i, name in enumerate(("about x", "about y", "about z")):
        ax.plot(t.t, np.degrees(angles[:, i]), label=name)
    ax.set_ylabel("base rotation (deg, accumulated)")
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    fz = t.forces[:, :, 2]
    for j, name in enumerate(t.contact_names):
        ax.plot(t.t, fz[:, j], lw=0.8, label=name if len(t.contact_names) <= 8 else None)
    ax.set_ylabel("contact force z (N)")
    ax.set_xlabel("time (s)")
    if len(t.contact_names) <= 8:
        ax.legend(fontsize=6, ncol=2)
    ax = axes[1, 1]
    ax.plot(t.t, t.tau[:, 6:], lw=0.6)
    ax.set_ylabel("joint torques (N m)")
    ax.set_xlabel("time (s)")
    turns = "" if result.turns is None else f", {result.turns:+.2f} turns"
    fig.suptitle(f"{result.task} on {result.robot}, {result.parameterization}: {result.status.value}, {result.iterations} iterations{turns} (grey: flight)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_convergence(result: Result, path: str | Path) -> Path:
    """Primal and dual infeasibility against Ipopt iteration."""
    plt = _pyplot()
    h = result.history
    fig, ax = plt.subplots(figsize=(5, 3.5))
    it = [r["iter"] for r in h]
    ax.semilogy(it, [r["inf_pr"] for r in h], label="primal infeasibility")
    ax.semilogy(it, [r["inf_du"] for r in h], label="dual infeasibility")
    ax.set_xlabel("Ipopt iteration")
    ax.legend()
    ax.set_title(f"{result.task} [{result.parameterization}]")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
