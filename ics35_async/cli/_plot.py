"""--plot: record position traces during a live command and draw them at the end (matplotlib).

The file name and format are checked before the line is touched, so a run
is never lost to a typo in the path at its end.
"""

from __future__ import annotations

import math

from .. import units
from ..extras import extra_hint
from ..frames import Frame
from ._paths import check_output_path
from ._settings import CliError, ExitCode


def require_matplotlib() -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CliError(
            ExitCode.USAGE,
            "--plot needs matplotlib, which is not installed",
            f"{extra_hint('plot')}  (or: pip install matplotlib)",
        ) from None


def plot_formats() -> frozenset[str]:
    """File suffixes matplotlib's Agg backend writes (png, pdf, svg, ...)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    return frozenset(FigureCanvasAgg.get_supported_filetypes())


def check_plot_path(path: str) -> None:
    """matplotlib is there, and ``path`` is writable with a suffix it can draw: else exit 2, nothing sent."""
    require_matplotlib()
    check_output_path(path, "--plot", plot_formats())


class Recorder:
    """Position traces for --plot."""

    def __init__(self, limit: int = 200_000) -> None:
        self.times: list[float] = []
        self.traces: dict[int, list[float]] = {}
        self.limit = limit

    def add(self, t: float, frame: Frame) -> None:
        if len(self.times) >= self.limit:
            return
        self.times.append(t)
        n = len(self.times)
        for sid, pos in frame.positions.items():
            trace = self.traces.setdefault(sid, [])
            trace.extend([math.nan] * (n - 1 - len(trace)))
            trace.append(units.position_to_degrees(pos))

    def write(self, path: str, title: str) -> None:
        """Draw the traces to ``path`` (its suffix names the format); a failure is a CliError."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(10, 5))
        for sid, trace in sorted(self.traces.items()):
            trace = trace + [math.nan] * (len(self.times) - len(trace))
            ax.plot(self.times, trace, label=f"ID {sid}", linewidth=1)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("position (degrees)")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
        if len(self.traces) <= 16:
            ax.legend(fontsize="small", ncol=2)
        fig.tight_layout()
        try:
            fig.savefig(path, dpi=100, format=path.rsplit(".", 1)[-1].lower())
        except (OSError, ValueError) as exc:
            # Checked up front; this is the file system changing during the run.
            raise CliError(ExitCode.COMMUNICATION, f"--plot {path}: could not write the plot: {exc}") from None
        finally:
            plt.close(fig)
