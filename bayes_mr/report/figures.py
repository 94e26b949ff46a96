"""Figures the thesis shows, from bayes_mr results, and the helpers every figure of the package uses.

Figures are made with matplotlib's object API (:class:`~matplotlib.figure.Figure`
on an Agg canvas), never through pyplot: importing or calling this module
leaves the user's backend and pyplot's figure list alone. Each plotting
function draws one figure and returns it; :func:`save` writes it as PNG.
Nothing here computes a result: figures show what the engines already stored.
"""

from __future__ import annotations

from pathlib import Path
from textwrap import fill

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **kwargs) -> tuple[Figure, object]:
    """A new figure on its own Agg canvas and its axes (arguments as :meth:`Figure.subplots`).

    Parameters
    ----------
    nrows, ncols : int
        Grid of axes.
    figsize : tuple of float
        Width and height [inch].
    **kwargs
        ``sharex``, ``sharey``, ``squeeze`` … passed to :meth:`Figure.subplots`.
    """
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)  # the figure's own canvas: no pyplot, no global backend
    return fig, fig.subplots(nrows, ncols, **kwargs)


def save(fig: Figure, path: str | Path, dpi: int = 110, metadata: dict | None = None) -> Path:
    """Write ``fig`` as PNG at ``dpi`` [dots per inch] (``metadata``: PNG text fields, as matplotlib's)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight", metadata=metadata)
    return path


def hysteresis(x: np.ndarray, curves: dict[str, np.ndarray], *, title: str = "", xlabel: str = "displacement [mm]",
               window: slice | None = None, scale_x: float = 1e3) -> Figure:
    """Force–displacement loops: each entry of ``curves`` is a force series [N]."""
    fig, ax = subplots(figsize=(5.5, 4.2))
    sl = slice(None) if window is None else window
    for i, (label, f) in enumerate(curves.items()):
        ax.plot(np.asarray(x)[sl] * scale_x, np.asarray(f)[sl], lw=0.8 if i else 1.2, label=label,
                alpha=0.9 if i else 0.6)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("force [N]")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


#: Longest legend label kept inside a panel [characters].
LEGEND_INSIDE = 40


def time_series(t: np.ndarray, panels: dict[str, dict[str, np.ndarray]], *, title: str = "",
                window: tuple[float, float] | None = None, colors: dict[str, str] | None = None) -> Figure:
    """Stacked panels of time series: ``panels[ylabel][label] = values``.

    ``colors`` (label → matplotlib colour) keeps one series the same colour in every panel.
    """
    # long labels (an extended model's name) go beside the panels, where they hide no data
    beside = any(len(label) > LEGEND_INSIDE for series in panels.values() for label in series)
    fig, axes = subplots(len(panels), 1, figsize=(11 if beside else 8, 2.1 * len(panels)), sharex=True,
                         squeeze=False)
    t = np.asarray(t)
    sl = slice(None) if window is None else (t >= window[0]) & (t <= window[1])
    for ax, (ylabel, series) in zip(axes[:, 0], panels.items()):
        for i, (label, y) in enumerate(series.items()):
            ax.plot(t[sl], np.asarray(y)[sl], lw=0.8, label=fill(label, 45), alpha=1.0 if i == 0 else 0.85,
                    color=(colors or {}).get(label))
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if beside:
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        else:
            ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def convergence(t: np.ndarray, history: dict[str, np.ndarray], truth: dict[str, float] | None = None,
                sd: dict[str, np.ndarray] | None = None, *, title: str = "") -> Figure:
    """Parameter convergence histories (thesis Fig. 3.8, 3.47, 5.24)."""
    names = list(history)
    fig, axes = subplots(len(names), 1, figsize=(7, 1.6 * len(names)), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        h = np.asarray(history[name])
        ax.plot(t, h, lw=0.9)
        if sd is not None and name in sd:
            ax.fill_between(t, h - 2 * sd[name], h + 2 * sd[name], alpha=0.2, lw=0)
        if truth and name in truth:
            ax.axhline(truth[name], color="k", ls="--", lw=0.8)
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def distributions(values: dict[str, np.ndarray], truth: dict[str, float] | None = None, *, title: str = "") -> Figure:
    """Histograms of trained models' parameters (thesis Fig. 3.27, 5.3–5.5)."""
    names = list(values)
    cols = min(3, len(names))
    rows = int(np.ceil(len(names) / cols))
    fig, axes = subplots(rows, cols, figsize=(3.2 * cols, 2.5 * rows), squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        v = np.asarray(values[name], float)
        v = v[np.isfinite(v)]
        if v.size:
            pos = np.all(v > 0) and v.max() / max(v.min(), 1e-300) > 30
            bins = np.geomspace(v.min(), v.max(), 20) if pos else 20
            ax.hist(v, bins=bins, color="tab:blue", alpha=0.75)
            if pos:
                ax.set_xscale("log")
        if truth and name in truth:
            ax.axvline(truth[name], color="k", ls="--", lw=1)
        ax.set_title(name, fontsize=9)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def binned(xs: dict[str, np.ndarray], r: np.ndarray, *, title: str = "", nbins: int = 30) -> Figure:
    """Residual ``r`` against several variables: binned mean ± SD (diagnose views)."""
    fig, axes = subplots(1, len(xs), figsize=(3.2 * len(xs), 2.8), squeeze=False)
    r = np.asarray(r, float)
    for ax, (label, x) in zip(axes[0], xs.items()):
        x = np.asarray(x, float)
        edges = np.quantile(x, np.linspace(0, 1, nbins + 1))
        edges = np.unique(edges)
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
        centers, mean, sd = [], [], []
        for b in range(edges.size - 1):
            sel = idx == b
            if sel.sum() > 3:
                centers.append(np.median(x[sel]))
                mean.append(r[sel].mean())
                sd.append(r[sel].std())
        centers, mean, sd = map(np.asarray, (centers, mean, sd))
        ax.plot(centers, mean, "o-", ms=3)
        ax.fill_between(centers, mean - sd, mean + sd, alpha=0.2)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("residual")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def command_loops(v: np.ndarray, curves: dict[str, np.ndarray], command: np.ndarray, *, title: str = "",
                  xlabel: str = "velocity [m/s]") -> Figure:
    """Force–velocity loops, one panel per force series [N], points coloured by the damper command.

    ``command`` is the voltage [V] or current [A] at each sample; the colour bar
    shows it, so a reader sees which branch belongs to the field on or off.
    """
    fig, axes = subplots(1, len(curves), figsize=(3.6 * len(curves), 3.4), sharey=True, squeeze=False)
    v = np.asarray(v, float)
    command = np.asarray(command, float)
    art = None
    for ax, (label, f) in zip(axes[0], curves.items()):
        art = ax.scatter(v, np.asarray(f, float), c=command, s=2, cmap="viridis", rasterized=True)
        ax.set_xlabel(xlabel)
        ax.set_title(fill(label, 34), fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("force [N]")
    fig.subplots_adjust(top=0.74)  # room for the title over the panels' wrapped titles (before the colour bar)
    if art is not None:
        fig.colorbar(art, ax=list(axes[0]), label="command")
    fig.suptitle(title)
    return fig


def bars(panels: dict[str, dict[str, float | None]], *, title: str = "", highlight: set[str] | None = None,
         reference: dict[str, float] | None = None) -> Figure:
    """Horizontal bars side by side: ``panels[xlabel][label] = value``, one panel per quantity.

    Labels keep their order from top to bottom; a value that is None or not finite leaves its bar out
    (the label stays, so the panels line up). Bars whose label is in ``highlight`` are drawn in a second
    colour (the selected model, the named effects); ``reference`` (xlabel → value) draws a dashed line
    in that panel (a threshold, a ratio of 1).
    """
    labels = list(dict.fromkeys(label for series in panels.values() for label in series))
    fig, axes = subplots(1, max(1, len(panels)), figsize=(3.6 * max(1, len(panels)) + 1.5,
                                                       0.9 + 0.32 * max(1, len(labels))),
                         sharey=True, squeeze=False)
    y = np.arange(len(labels))[::-1]
    for ax, (xlabel, series) in zip(axes[0], panels.items()):
        for yi, label in zip(y, labels):
            v = series.get(label)
            if v is None or not np.isfinite(float(v)):
                continue
            ax.barh(yi, float(v), color="tab:orange" if highlight and label in highlight else "tab:blue",
                    alpha=0.85)
        if reference and xlabel in reference:
            ax.axvline(reference[xlabel], color="k", ls="--", lw=0.8)
        ax.axvline(0.0, color="k", lw=0.6)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3, axis="x")
    axes[0, 0].set_yticks(y, [fill(label, 34) for label in labels], fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _levels(values: list[float], tolerance: float = 0.1) -> tuple[list[float], list[int]]:
    """Nominal levels of a test matrix's conditions, and the level of each value.

    Amplitudes and frequencies estimated from records scatter about the nominal level
    they were run at (noise widens a peak-to-peak by a few per cent): sorted values
    within ``tolerance`` (relative) of the previous one share a level, labelled by
    its median.
    """
    order = np.argsort(values)
    groups: list[list[int]] = []
    for i in order:
        if groups and abs(values[i] - values[groups[-1][-1]]) <= tolerance * abs(values[groups[-1][-1]]):
            groups[-1].append(int(i))
        else:
            groups.append([int(i)])
    index = [0] * len(values)
    for g, members in enumerate(groups):
        for i in members:
            index[i] = g
    return [float(np.median([values[i] for i in members])) for members in groups], index


def condition_map(rows: list[dict], *, value: str = "force_nrmse", label: str = "force NRMSE [-]",
                  title: str = "") -> Figure:
    """A heat map of a score by test condition: amplitude × frequency, one panel per constant command.

    Parameters
    ----------
    rows : list of dict
        One per test, with ``amplitude`` [m], ``frequency`` [Hz], ``command`` (``current``, ``voltage``
        or None), ``command_value`` [A or V] and the score ``value`` (the rows of ``validate``'s
        ``by_condition`` or of a leave-one-condition-out ``table``).
    value : str
        The key of the score coloured and printed in each cell.
    label : str
        The colour bar's label, with its unit.
    title : str
        The figure's title.

    Returns
    -------
    Figure
        Cells coloured on one scale across panels (from 0 to the largest score), the score printed in
        each; a condition not tested is left blank. Amplitudes [mm] and frequencies [Hz] within 10 % of
        each other share a level (:func:`_levels`), labelled by its median; of repeats of one cell the
        last one shows.
    """
    def cmd(r):
        return (r.get("command") or "", r.get("command_value"))

    panels = sorted({cmd(r) for r in rows}, key=lambda c: (c[0], -np.inf if c[1] is None else c[1]))
    amps, amp_of = _levels([1e3 * r["amplitude"] for r in rows])
    freqs, freq_of = _levels([r["frequency"] for r in rows])
    scores = [r[value] for r in rows if r.get(value) is not None]
    vmax = max(scores) if scores else 1.0
    fig = Figure(figsize=(1.6 + (0.8 * len(freqs) + 1.0) * len(panels), 1.6 + 0.55 * len(amps)),
                 layout="constrained")  # room for the panel titles, the colour bar and the title
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, panel in zip(axes[0], panels):
        grid = np.full((len(amps), len(freqs)), np.nan)
        for k, r in enumerate(rows):
            if cmd(r) == panel and r.get(value) is not None:
                grid[amp_of[k], freq_of[k]] = r[value]
        image = ax.imshow(grid, origin="lower", cmap="viridis", vmin=0.0, vmax=vmax, aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            if np.isfinite(v):  # dark text on the light end of the scale, light text on the dark end
                ax.text(j, i, f"{v:.3f}", ha="center", va="center", fontsize=8,
                        color="k" if v > 0.6 * vmax else "w")
        ax.set_xticks(range(len(freqs)), [f"{f:.3g}" for f in freqs])
        ax.set_yticks(range(len(amps)), [f"{a:.3g}" for a in amps])
        ax.set_xlabel("frequency [Hz]")
        name, level = panel
        unit = {"current": "A", "voltage": "V"}.get(name, "")
        ax.set_title(f"{name} {level:g} {unit}" if level is not None else (f"{name} varying" if name
                                                                               else "no command"), fontsize=9)
    axes[0, 0].set_ylabel("displacement amplitude [mm]")
    fig.colorbar(image, ax=list(axes[0]), label=label, shrink=0.9)
    fig.suptitle(title)
    return fig
