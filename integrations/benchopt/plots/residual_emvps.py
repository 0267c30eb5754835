"""The verified residual against E-MVPs, per solver: the method paper's axis in benchopt.

benchopt's own curves are against time or iterations; one lcpbench iteration may cost one
product or several, and on a suspension a product is a Stokes solve, so the products are the
axis that compares solvers. Each point is one of benchopt's sampled iterates, the median over
repetitions (the E-MVPs of a sampled iterate are the same in every repetition).
"""

from benchopt import BasePlot


class Plot(BasePlot):
    name = "Residual against E-MVPs"
    type = "scatter"
    options = {"dataset": ..., "objective": ...}

    def plot(self, df, dataset, objective):
        df = df.query("dataset_name == @dataset and objective_name == @objective")
        traces = []
        for solver, rows in df.groupby("solver_name"):
            curve = rows.groupby("stop_val")[["objective_emvps", "objective_value"]].median()
            curve = curve.sort_values("objective_emvps")
            traces.append({"x": curve["objective_emvps"].tolist(),
                           "y": curve["objective_value"].tolist(),
                           "label": solver, **self.get_style(solver)})
        return traces

    def get_metadata(self, df, dataset, objective):
        return {"title": f"{objective}\nData: {dataset}", "xlabel": "E-MVPs",
                "ylabel": "verified ||min(x, Ax + b)||"}
