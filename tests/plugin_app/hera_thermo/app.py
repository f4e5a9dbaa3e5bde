"""The thermo application: truth, scores, plot and live panel for hera eval and hera up."""

from pathlib import Path

import numpy as np

from hera.application import Application, FunctionTruth, Metric, Panel
from hera_thermo.measures import room

TEMP = "temperature [degC]"


class ThermoApp(Application):
    name = "thermo"
    title = "a room thermometer and its Kalman filter"
    measures = ("thermo", "thermo_filter")
    metrics = (Metric("rmse_degc", "RMSE", "degC"), Metric("max_degc", "max error", "degC"))

    def truth(self, world):
        return FunctionTruth((TEMP,), lambda t: {TEMP: room(world, t)})

    def score(self, series, truth, options):
        settled = series.t - series.t[0] >= options.after
        err = series.column(TEMP)[settled] - [truth.at(t)[TEMP] for t in series.t[settled]]
        return {"rmse_degc": float(np.sqrt(np.mean(err**2))), "max_degc": float(max(abs(err)))}

    def plots(self, series, truth, out_dir, options):
        from hera.plotting import pyplot

        plt = pyplot()
        fig, ax = plt.subplots()
        for s in series:
            ax.plot(s.t - s.t[0], s.column(TEMP), label=s.name)
        t = series[0].t
        ax.plot(t - t[0], [truth.at(x)[TEMP] for x in t], "k--", label="truth")
        ax.legend()
        fig.savefig(out_dir / "thermo.png")
        plt.close(fig)
        return [out_dir / "thermo.png"]

    def panel(self, estimates, truth):
        rows = []
        for e in estimates:
            true = truth.at(e.t)[TEMP]
            rows.append((e.name, e.node, f"{e.values[TEMP]:.2f}", f"{e.values[TEMP] - true:+.2f}"))
        return Panel("thermo", ("model", "node", "degC", "error"), tuple(rows))

    def examples(self):
        return {"thermo": Path(__file__).with_name("thermo.toml")}
