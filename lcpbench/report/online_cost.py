"""Which E-MVPs the online views use: the cost model's where a row has them, else the timed.

``lcpbench simulate`` writes two E-MVP figures per step: ``emvps``, each low product
weighed by the cost ratio timed in that step (the paper's way, which varies from run to
run), and ``model_emvps``, each low priced by its inner applications times a cost per
application calibrated once per run (:mod:`lcpbench.workflows.cost_model`), which is the
same in identical runs. The online views read ``emvps`` after :func:`with_model_emvps`:
the model's figure where the row has one, the timed one for rows written before the model
existed (their numbers are unchanged), and always the timed one in ``timed_emvps``.
"""

from __future__ import annotations

import pandas as pd

__all__ = ["with_model_emvps"]


def with_model_emvps(on: pd.DataFrame) -> pd.DataFrame:
    """``on`` (online rows) with ``emvps`` the model E-MVPs where recorded (``model_emvps``
    finite) and ``timed_emvps`` the per-step timed E-MVPs of every row."""
    out = on.copy()
    timed = pd.to_numeric(out["emvps"], errors="coerce") if "emvps" in out else None
    out["timed_emvps"] = timed
    if "model_emvps" in out and timed is not None:
        model = pd.to_numeric(out["model_emvps"], errors="coerce")
        out["emvps"] = model.where(model.notna(), timed)
    return out
