"""The method paper's experiment as one Markdown results page, generated from run stores.

``lcpbench paper DIR`` reads every run store directly under ``DIR`` (a folder with a
``results.csv``) and writes ``DIR/README.md``:

* at the top, per store: what it holds (online regime or offline), the command that wrote
  it, the commit, the machine and its threads, the time span of its rows and the load
  average the rows recorded (in the manner of qpbenchmark's results pages);
* the online comparison per regime and lattice beside the paper's online table: BB-PGD's
  summed total and collision-resolution seconds, both speedups of Mono-PQN and Bi-PQN
  (ratios of sums over the same compared steps), and per solver the median E-MVPs, high
  MVPs and application-weighted cost; the steps left out of the comparison (the warm-up
  step, steps without contacts or without products) listed apart;
* the offline comparison per stored set beside the paper's offline table
  (:mod:`.paper_offline`);
* the held-apart choice of the configurations lcpbench's best regime runs
  (:mod:`.paper_select`), from the store named ``select``;
* one section, "What differs", that states the measured differences with numbers from
  the same rows.

Everything on the page comes from the stores' rows and ``meta.json``: rendering the same
stores again gives the same page, byte for byte (no clock is read).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER, PAPER_OFFLINE_HEADLINE, PAPER_ONLINE_FAMILIES
from lcpbench.core.ranges import format_ranges
from lcpbench.report import paper_offline, paper_online, paper_select, tables
from lcpbench.report.markup import markdown_table as md_table
from lcpbench.run.store import RunStore

__all__ = ["PAGE_NAME", "find_stores", "render_page", "write_page"]

PAGE_NAME = "README.md"
"""The page's file name inside the folder (shown by code hosts when the folder is opened)."""

REGIME_TITLES = {
    "paper": "the paper's regime (no Krylov recycling, no quasi-Newton memory across "
             "steps, the paper's products)",
    "default": "lcpbench's regime (Krylov recycling and quasi-Newton memory across steps)",
}


def find_stores(folder: Path) -> list[Path]:
    """The run stores directly under ``folder`` (sub-folders holding a ``results.csv``),
    sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{str(folder)!r} is not a folder; give the folder that holds "
                                "the run stores (e.g. reports/paper)")
    return sorted(p for p in folder.iterdir()
                  if p.is_dir() and not p.is_symlink() and (p / "results.csv").is_file())


def _fmt(v, digits: int = 3, suffix: str = "") -> str:
    if v is None or (isinstance(v, (float, np.floating)) and not np.isfinite(v)):
        return "-"
    if isinstance(v, (int, np.integer)):
        return f"{int(v)}{suffix}"
    return f"{float(v):.{digits}g}{suffix}"


def _speed(v) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{float(v):.2f}x"


def _seconds(v) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{float(v):.0f}"


def _regime(rows: pd.DataFrame, meta: dict) -> str:
    """``paper`` / ``default`` for an online store (from its rows' ``info``, else its
    meta), ``offline`` for a store of offline runs."""
    if rows.empty or (rows["kind"] != "online").all():
        return "offline"
    seen: set[str] = set()
    for text in rows.loc[rows["kind"] == "online", "info"].dropna():
        try:
            r = json.loads(text).get("regime")
        except (ValueError, AttributeError):
            continue
        if isinstance(r, str):
            seen.add(r)
    if len(seen) > 1:
        raise ValueError(f"one store holds online rows of several regimes ({sorted(seen)}); "
                         "keep each regime in a store of its own")
    if seen:
        return seen.pop()
    return str((meta.get("config") or {}).get("regime", "default"))


def _load(rows: pd.DataFrame) -> str:
    """Median and largest one-minute load average the rows recorded."""
    loads = []
    for text in rows["info"].dropna():
        try:
            v = json.loads(text).get("load_1min")
        except (ValueError, AttributeError):
            continue
        if isinstance(v, (int, float)):
            loads.append(float(v))
    if not loads:
        return "-"
    return f"median {np.median(loads):.2f}, max {max(loads):.2f}"


def _threads(meta: dict) -> str:
    th = ((meta.get("machine") or {}).get("threads") or {})
    set_ = {k: v for k, v in sorted(th.items()) if v is not None}
    return ", ".join(f"{k}={v}" for k, v in set_.items()) or "library defaults"


def _store_header(name: str, rows: pd.DataFrame, meta: dict, regime: str) -> list[str]:
    machine = meta.get("machine") or {}
    started = sorted(str(s) for s in rows.get("started", pd.Series(dtype=str)).dropna())
    finished = sorted(str(s) for s in rows.get("finished", pd.Series(dtype=str)).dropna())
    span = f"{started[0]} to {finished[-1]}" if started and finished else "-"
    blas = (machine.get("blas") or {}).get("name", "-")
    what = "offline runs" if regime == "offline" else REGIME_TITLES.get(regime, regime)
    return [f"- **`{name}/`**: {what}; {len(rows)} rows",
            f"  - command: `{' '.join(str(a) for a in meta.get('argv') or []) or '-'}`",
            f"  - commit {str(meta.get('git_commit') or '-')[:12]}; "
            f"rows written {span}",
            f"  - machine: {machine.get('cpu', '-')}, {machine.get('cpu_count', '-')} cores, "
            f"{blas}; threads: {_threads(meta)}; load average over the rows: {_load(rows)}"]


# ---------------------------------------------------------------------------- online

def _online_rows(paper: pd.DataFrame, regime: str, baseline: str) -> list[dict]:
    """Per lattice, lcpbench's row then the paper's: the online table in page form."""
    both = paper_online.beside_paper(paper, baseline)
    out = []
    for _, r in both.iterrows():
        measured = r["source"] != "paper"
        if not measured and not (both["lattice size"] == r["lattice size"]).sum() > 1:
            continue                            # a paper size with no measured row
        out.append({
            "size": r["lattice size"],
            "source": f"lcpbench, {regime} regime" if measured else "paper",
            "steps": _fmt(r["steps"]),
            "BB-PGD total s": _seconds(r["BB-PGD total s"]),
            "BB-PGD collision s": _seconds(r["BB-PGD collision s"]),
            "Mono-PQN total": _speed(r["Mono-PQN total speedup"]),
            "Mono-PQN collision": _speed(r["Mono-PQN collision speedup"]),
            "Bi-PQN total": _speed(r["Bi-PQN total speedup"]),
            "Bi-PQN collision": _speed(r["Bi-PQN collision speedup"])})
    return out


def _median_rows(paper: pd.DataFrame, steps: pd.DataFrame) -> list[dict]:
    """Per lattice and solver the medians over the compared steps; a store whose rows carry
    the cost model's E-MVPs (``model_emvps``) also shows the per-step timed ones."""
    modelled = "model_emvps" in steps and bool(
        pd.to_numeric(steps["model_emvps"], errors="coerce").notna().any())
    out = []
    for _, r in paper.iterrows():
        for s in paper.attrs.get("solvers", []):
            g = steps[(steps["problem"] == r["scene"]) & (steps["solver"] == s)]
            row = {"size": r["lattice size"], "solver": f"`{s}`",
                   "compared steps": str(len(g)),
                   "solved": f"{int(tables.solved_mask(g).sum())}/{len(g)}",
                   "median E-MVPs": _fmt(r.get(f"{s} median E-MVPs")),
                   "median high MVPs": _fmt(r.get(f"{s} median MVPs")),
                   "median app. cost": _fmt(r.get(f"{s} median app cost"))}
            if modelled:
                row["median timed E-MVPs"] = _fmt(r.get(f"{s} median timed E-MVPs"))
            out.append(row)
    return out


def _left_out_rows(res: pd.DataFrame) -> list[dict]:
    apart = tables.online_left_out(res)
    out = []
    for (scene, reason), g in (apart.groupby(["scene", "reason"], sort=False)
                               if len(apart) else []):
        steps = sorted({int(k) for s in g["steps"] for k in str(s).split(",")})
        out.append({"scene": f"`{scene}`", "reason": reason,
                    "steps": format_ranges(steps, ", "), "count": str(len(steps))})
    return out


def _online_section(name: str, res: pd.DataFrame, regime: str, baseline: str,
                    findings: list[str]) -> list[str]:
    paper = tables.online_paper_table(res, baseline)
    steps = tables.online_step_rows(res)
    title = REGIME_TITLES.get(regime, regime)
    lines = [f"### Online, {title} (`{name}/`)", ""]
    if paper.empty:
        return lines + ["No compared step yet.", ""]
    lines += ["Speedups are BB-PGD's summed seconds over the solver's, over the steps every "
              "solver of the lattice finished (the compared steps); total is the whole time "
              "step, collision the LCP solve.", ""]
    lines += [md_table(pd.DataFrame(_online_rows(paper, regime, baseline))), ""]
    modelled = "model_emvps" in steps and bool(
        pd.to_numeric(steps["model_emvps"], errors="coerce").notna().any())
    lines += [("Per solver over the compared steps (E-MVPs price each low by its inner "
               "applications times a cost per application calibrated once per run, "
               "`model_emvps`; the timed E-MVPs weigh each low product by the cost ratio "
               "timed in its step, as the paper; " if modelled else
               "Per solver over the compared steps (E-MVPs weigh each low-fidelity product "
               "by its measured cost ratio; ")
              + "the application-weighted cost counts inner Krylov applications, in cold "
              "high products):", ""]
    lines += [md_table(pd.DataFrame(_median_rows(paper, steps))), ""]
    left = _left_out_rows(res)
    if left:
        lines += ["Steps left out of the comparison and of the medians:", "",
                  md_table(pd.DataFrame(left)), ""]
    stored = paper.attrs.get("stored", {})
    cut = {sc: v for sc, v in stored.items() if len(set(v.values())) > 1}
    for sc, v in sorted(cut.items()):
        lines += [f"Stored steps differ on `{sc}` ("
                  + ", ".join(f"{s}: {k}" for s, k in sorted(v.items()))
                  + "): the comparison uses the steps all finished.", ""]
    _online_findings(paper, regime, baseline, findings)
    return lines


def _online_findings(paper: pd.DataFrame, regime: str, baseline: str,
                     findings: list[str]) -> None:
    solvers = list(paper.attrs.get("solvers") or [])
    fam = {k: next((s for s in solvers if s == v or s.startswith(v + ":")), None)
           for k, v in PAPER_ONLINE_FAMILIES.items()}
    for _, r in paper.iterrows():
        side = int(round(float(r["M"]) ** (1 / 3))) if np.isfinite(r["M"]) else None
        ref = paper_online.PAPER_ONLINE.get(side) if side is not None else None
        if ref is None:
            continue
        parts = []
        for label, key in (("Mono-PQN", "mono"), ("Bi-PQN", "bi")):
            s = fam[label]
            if s is None:
                continue
            parts.append(f"{label} {_speed(r[f'{s} total speedup'])} total and "
                         f"{_speed(r[f'{s} collision speedup'])} collision against the "
                         f"paper's {ref[key + '_total']:.2f}x and "
                         f"{ref[key + '_collision']:.2f}x")
        share = (r[f"{baseline} collision s"] / r[f"{baseline} total s"]
                 if r[f"{baseline} total s"] else np.nan)
        paper_share = ref["collision_s"] / ref["total_s"]
        findings.append(
            f"Online {r['lattice size']}, {regime} regime, {int(r['steps'])} compared steps: "
            + "; ".join(parts) + f". Collision resolution is {share:.0%} of BB-PGD's step "
            f"time here and {paper_share:.0%} in the paper, so a collision speedup moves the "
            f"total {'more' if share > paper_share else 'less'} here.")


# ---------------------------------------------------------------------------- offline

def _offline_section(name: str, res: pd.DataFrame, baseline: str,
                     findings: list[str]) -> list[str]:
    off = tables.offline_runs(res)
    lines = [f"### Offline (`{name}/`)", "",
             "Median E-MVPs over the verified-solved runs of each stored set, over the "
             "instances every solver of the paper's table was given, beside the paper's "
             "offline table (its 50 LCPs of a 125-sphere simulation); the ratios to BB-PGD "
             "are the comparable figures.", ""]
    for problem in sorted(off["problem"].astype(str).unique()):
        t = paper_offline.beside_paper(off, problem, baseline)
        if t.empty:
            continue
        lines += [f"**`{problem}`** ({t.attrs['instances']} instances)", ""]
        show = pd.DataFrame({
            "solver": [f"`{s}`" for s in t["solver"]], "paper method": t["paper method"],
            "solved": t["solved"],
            "median E-MVPs (high)": [_with_high(e, h, s) for e, h, s in
                                     zip(t["median E-MVPs"], t["median high MVPs"],
                                         t["solver"])],
            "paper (high)": [_with_high(e, h, s) for e, h, s in
                             zip(t["paper median E-MVPs"], t["paper median high MVPs"],
                                 t["solver"])],
            f"/ {baseline}": [_fmt(v) for v in t[f"/ {BASELINE_SOLVER}"]],
            f"paper / {baseline}": [_fmt(v) for v in t[f"paper / {BASELINE_SOLVER}"]]})
        lines += [md_table(show), ""]
        _offline_findings(problem, t, findings)
    return lines


def _with_high(e, h, solver: str) -> str:
    row = paper_offline.paper_row_of(solver)
    if row is not None and row.high is not None and h is not None and np.isfinite(h):
        return f"{_fmt(e)} ({_fmt(h)})"
    return _fmt(e)


def _offline_findings(problem: str, t: pd.DataFrame, findings: list[str]) -> None:
    col, pcol = f"/ {BASELINE_SOLVER}", f"paper / {BASELINE_SOLVER}"
    bits = []
    for _, r in t.iterrows():
        if r["solver"] in PAPER_OFFLINE_HEADLINE and np.isfinite(r[col]):
            bits.append(f"{r['paper method']} {r[col]:.2f} of BB-PGD's E-MVPs against the "
                        f"paper's {r[pcol]:.2f}")
    base = t[t["solver"] == BASELINE_SOLVER]
    if len(base) and np.isfinite(base["median E-MVPs"].iloc[0]):
        bits.append(f"BB-PGD needs a median {base['median E-MVPs'].iloc[0]:.3g} E-MVPs against "
                    "the paper's 11 (lcpbench stops at a verified residual of 1e-8)")
    if bits:
        findings.append(f"Offline `{problem}`: " + "; ".join(bits) + ".")


# ---------------------------------------------------------------------------- page

def render_page(folder: Path, baseline: str = BASELINE_SOLVER) -> str:
    """The Markdown results page of the run stores directly under ``folder``.

    Raises
    ------
    FileNotFoundError
        When ``folder`` is not a folder or holds no run store.
    """
    folder = Path(folder)
    stores = find_stores(folder)
    if not stores:
        raise FileNotFoundError(f"{str(folder)!r} holds no run store (a sub-folder with a "
                                "results.csv); run sweeps/online-paper.sh or lcpbench run "
                                "--config sweeps/paper-offline.toml into it first")
    loaded = []
    for path in stores:
        store = RunStore(path)
        res, meta = store.results(), store.read_meta() or {}
        loaded.append((path.name, res, meta, _regime(res, meta)))
    order = {"paper": 0, "default": 1, "offline": 2}
    loaded.sort(key=lambda t: (order.get(t[3], 3), t[0]))
    findings: list[str] = []
    lines = ["# The method paper's experiment, measured by lcpbench", "",
             f"Generated by `lcpbench paper {folder.as_posix()}` from the run stores in this "
             "folder; rerun it after a run adds rows. Every number below is computed from the "
             "stores' `results.csv`; none is typed in, except the paper's own figures.", "",
             "## The run stores", ""]
    for name, res, meta, regime in loaded:
        lines += _store_header(name, res, meta, regime)
    for name, res, _meta, _regime_name in loaded:
        if name == paper_select.SELECT_STORE:
            lines += [""] + paper_select.selection_section(name, res)
    lines += ["", "## Online comparison", ""]
    online = [t for t in loaded if t[3] != "offline" and t[0] != paper_select.SELECT_STORE]
    if not online:
        lines += ["No online store yet.", ""]
    for name, res, _meta, regime in online:
        lines += _online_section(name, res, regime, baseline, findings)
    lines += ["## Offline comparison", ""]
    offline = [t for t in loaded if t[3] == "offline"]
    if not offline:
        lines += ["No offline store yet.", ""]
    for name, res, _meta, _regime_name in offline:
        lines += _offline_section(name, res, baseline, findings)
    lines += ["## What differs", ""]
    lines += [f"- {f}" for f in findings] or ["- Nothing measured yet."]
    lines += ["", "Why the figures differ from the paper's, in general: the paper ran a "
              "Stokes FMM far field on 24 cores; lcpbench sums the far field directly or by a "
              "table on two cores, so the share of a step that collision resolution takes, and "
              "with it how far a collision speedup moves the total, differ. lcpbench stops at a verified residual, so "
              "every solver needs more products than in the paper. Its regime (`default`) "
              "recycles Krylov directions across products, which makes later products of a "
              "solve cheaper and changes which solver is fastest. The low fidelity's error "
              "against the high decides how many high products Bi-PQN needs.", ""]
    return "\n".join(lines)


def write_page(folder: Path, out: Path | None = None,
               baseline: str = BASELINE_SOLVER) -> Path:
    """Render :func:`render_page` and write it to ``out`` (default ``folder/README.md``),
    atomically (a temporary file moved into place); returns the path written."""
    folder = Path(folder)
    text = render_page(folder, baseline)
    target = Path(out) if out is not None else folder / PAGE_NAME
    if target.is_symlink():
        raise FileExistsError(f"{str(target)!r} is a symbolic link; lcpbench does not write "
                              "through links: remove it or choose another --out")
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".md", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
