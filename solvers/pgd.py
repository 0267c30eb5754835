"""Projected gradient family (placeholder being replaced)."""
from dataclasses import dataclass
import numpy as np
from lcpbench import register_solver


@dataclass(frozen=True)
class BBPGDParams:
    """Parameters of bb-pgd."""
    variant: str = "bb1"


@register_solver("bb-pgd", BBPGDParams)
def bb_pgd(ctx, p):
    """Projected gradient with the Barzilai-Borwein step."""
    x = ctx.x0.copy()
    g = ctx.A @ x + ctx.b
    if ctx.report(x, g):
        return ctx.finish(x, g)
    Ag = ctx.A @ g
    tau = (g @ g) / max(g @ Ag, 1e-300)
    while True:
        xn = np.maximum(x - tau * g, 0)
        gn = ctx.A @ xn + ctx.b
        s, y = xn - x, gn - g
        x, g = xn, gn
        if ctx.report(x, g):
            return ctx.finish(x, g)
        sy = s @ y
        tau = (s @ s) / sy if sy > 0 else tau
