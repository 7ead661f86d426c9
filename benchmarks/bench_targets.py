"""The performance goals checked against one run's figures.

Each goal is a ratio or a time from the same ``make bench`` run; a section
that did not run leaves its goals out.  The stream and sequential goals
are read from section A (lean responder), with the default driver on the
default asyncio loop, and the best of every driver x loop row.
"""

from __future__ import annotations

from typing import Any

STREAM_CPU_VS_RAW_DEFAULT = 1.0  # stream CPU per transaction, default driver + asyncio, over raw pyserial's
STREAM_CPU_VS_RAW_BEST = 0.8  # the same with the best driver x loop
STREAM_RATE_VS_RAW = 1.0
SEQUENTIAL_RATE_VS_RAW = 0.9
LINES_AGGREGATE_VS_ONE = 3.6
SCAN_S = 2.0
SET_ID_S = 1.0
IMPORT_S = 0.060
VERSION_S = 0.150
P99_WAIT_TX = 1.5
MEMORY_MIB_PER_1M = 2.0
WEB_PAGE_VS_NO_PAGE = 0.90  # the stream with the Live plots page open, over no page open
STREAM_VS_ADAPTER_BOUND = 0.95  # the stream behind the FTDI model, over the model's ideal-host rate

DEFAULT_ROW = "asyncio/asyncio"  # the driver x loop a user gets without choosing (open_bus under asyncio.run)


def targets(results: dict[str, Any]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []

    def add(name: str, measured: str, goal: str, met: bool | None) -> None:
        out.append({"target": name, "measured": measured, "goal": goal, "met": met})

    cpu = results.get("cpu")
    if isinstance(cpu, dict) and "rows" in cpu:
        raw = cpu["raw"]
        add(
            "raw blocking pyserial (lean responder)",
            f"{raw['cpu_us_per_tx']:.1f} us/tx, {raw['tx_per_s']:.0f} tx/s",
            "",
            None,
        )
        for r in cpu["rows"]:
            add(
                f"{r['row']} (lean responder)",
                f"{r['cpu_us_per_tx']:.1f} us/tx = {r['cpu_vs_raw']:.2f}x raw; {r['tx_per_s']:.0f} tx/s = "
                f"{r['rate_vs_raw']:.2f}x raw",
                "",
                None,
            )
        rows = {r["row"]: r for r in cpu["rows"]}
        streams = [r for r in cpu["rows"] if r["row"].startswith("stream ")]
        seqs = [r for r in cpu["rows"] if r["row"].startswith("sequential ")]
        default = rows.get(f"stream {DEFAULT_ROW}")

        def floor(kind: str, loop: str) -> str:
            row = rows.get(f"loop floor {kind} {loop}")
            return f"{row['cpu_vs_raw']:.2f}x CPU, {row['rate_vs_raw']:.2f}x rate" if row else "-"

        if default and streams:
            best = min(streams, key=lambda r: r["cpu_vs_raw"])
            add(
                "stream CPU per transaction vs raw pyserial (default driver, asyncio)",
                f"{default['cpu_vs_raw']:.2f}x ({default['cpu_us_per_tx']:.1f} us, raw "
                f"{cpu['raw']['cpu_us_per_tx']:.1f} us); asyncio's own pass per transaction with no "
                f"library: {floor('stream', 'asyncio')}",
                f"<= {STREAM_CPU_VS_RAW_DEFAULT}x",
                default["cpu_vs_raw"] <= STREAM_CPU_VS_RAW_DEFAULT,
            )
            add(
                "stream CPU per transaction vs raw pyserial (best choice)",
                f"{best['cpu_vs_raw']:.2f}x {best['row']}",
                f"<= {STREAM_CPU_VS_RAW_BEST}x",
                best["cpu_vs_raw"] <= STREAM_CPU_VS_RAW_BEST,
            )
            add(
                "stream rate vs raw pyserial (lean responder)",
                "; ".join(f"{r['row'][7:]} {r['rate_vs_raw']:.2f}x" for r in streams),
                f">= {STREAM_RATE_VS_RAW}x",
                default["rate_vs_raw"] >= STREAM_RATE_VS_RAW,
            )
        seq = rows.get(f"sequential {DEFAULT_ROW}")
        if seq:
            add(
                "sequential awaited set_position rate vs raw pyserial",
                "; ".join(f"{r['row'][11:]} {r['rate_vs_raw']:.2f}x" for r in seqs)
                + f"; an awaited future per transaction with no library: asyncio {floor('sequential', 'asyncio')}, "
                f"uvloop {floor('sequential', 'uvloop')}",
                f">= {SEQUENTIAL_RATE_VS_RAW}x",
                seq["rate_vs_raw"] >= SEQUENTIAL_RATE_VS_RAW,
            )
    wire = results.get("wire")
    if isinstance(wire, dict) and "bauds" in wire:
        for b in wire["bauds"]:
            if b["baud"] not in (115200, 1250000):
                continue
            d = next((v for v in b["variants"] if v["loop"] == "asyncio"), None)
            if d:
                add(
                    f"stream rate vs raw pyserial, real-time simulator at {b['baud']}",
                    "; ".join(f"{v['loop']}/{v['transport']} {v['vs_raw']:.2f}x" for v in b["variants"]),
                    f">= {STREAM_RATE_VS_RAW}x",
                    d["vs_raw"] >= STREAM_RATE_VS_RAW,
                )
    lines = results.get("lines")
    if isinstance(lines, dict) and lines.get("rows"):
        by = {r["variant"]: r for r in lines["rows"]}
        d = by.get(DEFAULT_ROW, lines["rows"][0])
        add(
            f"{lines['lines']} lines x 32 servos at {lines['baud']}: aggregate cycles vs one line's",
            "; ".join(f"{r['variant']} {r['aggregate_vs_one_line']:.2f}x" for r in lines["rows"]),
            f">= {LINES_AGGREGATE_VS_ONE}x",
            d["aggregate_vs_one_line"] >= LINES_AGGREGATE_VS_ONE,
        )
    startup = results.get("startup")
    if isinstance(startup, dict) and "imports" in startup:
        im = startup["imports"]
        t_import, t_version = im["import_ics35_async"]["best_s"], im["ics35_version"]["best_s"]
        add("import ics35_async", f"{t_import * 1e3:.0f} ms", f"<= {IMPORT_S * 1e3:.0f} ms", t_import <= IMPORT_S)
        add("ics35 --version", f"{t_version * 1e3:.0f} ms", f"<= {VERSION_S * 1e3:.0f} ms", t_version <= VERSION_S)
    scan = results.get("scan")
    if isinstance(scan, dict) and "scan" in scan:
        s, si = scan["scan"]["best_s"], scan["set_id"]["best_s"]
        add("ics35 scan, 3 rates x 32 IDs, 3 servos (pty)", f"{s:.2f} s", f"<= {SCAN_S:g} s", s <= SCAN_S)
        add("ics35 set-id (pty)", f"{si:.2f} s", f"<= {SET_ID_S:g} s", si <= SET_ID_S)
    sh = results.get("sharing")
    if isinstance(sh, dict) and "rows" in sh:
        paced = [r for r in sh["rows"] if r["polling"] == "paced"]
        if paced:
            worst = max(paced, key=lambda r: r["wait_p99_tx"])
            add(
                "telemetry p99 wait while streaming",
                "; ".join(f"{r['baud']} {r['loop']}: {r['wait_p99_tx']:.2f}T" for r in paced),
                f"<= {P99_WAIT_TX:g} position-transaction times",
                worst["wait_p99_tx"] <= P99_WAIT_TX,
            )
    mem = results.get("memory")
    if isinstance(mem, dict) and "rows" in mem:
        worst_mem = max(mem["rows"], key=lambda r: r["growth_mib"])
        per_1m = worst_mem["growth_mib"] * 1e6 / worst_mem["transactions"]
        add(
            "memory growth per 1M transactions",
            "; ".join(f"{r['case']} {r['loop']}: {r['growth_mib']:.2f} MiB" for r in mem["rows"]),
            f"< {MEMORY_MIB_PER_1M:g} MiB",
            per_1m < MEMORY_MIB_PER_1M,
        )
    adapter = results.get("adapter")
    if isinstance(adapter, dict) and "rows" in adapter:
        for row in adapter["rows"]:
            add(
                f"stream behind the FTDI model, latency timer {row['latency_timer_ms']} ms",
                f"{row['stream_cycles_per_s']:.1f} cycles/s = {row['stream_vs_bound']:.0%} of the adapter bound "
                f"{row['adapter_bound_cycles_per_s']:.1f} (raw pyserial: {row['raw_vs_bound']:.0%})",
                f">= {STREAM_VS_ADAPTER_BOUND:.0%} of the adapter bound",
                row["stream_vs_bound"] >= STREAM_VS_ADAPTER_BOUND,
            )
    web = results.get("web")
    if isinstance(web, dict) and "page_vs_no_page" in web:
        noise = web["noise_floor_each"]
        add(
            "32-servo stream with the Live plots page open",
            f"{web['page_vs_no_page']:.0%} of no page (server CPU {web['server_cpu_ms_per_update'] or 0:.2f} ms per "
            f"update; no page vs no page: {min(noise, default=1):.0%}..{max(noise, default=1):.0%})",
            f">= {WEB_PAGE_VS_NO_PAGE:.0%} of no page",
            web["page_vs_no_page"] >= WEB_PAGE_VS_NO_PAGE,
        )
    return out


def print_targets(rows: list[dict[str, Any]]) -> None:
    """The one summary table of the run: every headline figure, its goal, and whether it is met."""
    print("\nSummary and goals (ratios and times from this run)\n")
    print("| figure | measured | goal | met |")
    print("|---|---|---|---|")
    for r in rows:
        status = {True: "yes", False: "**NO**", None: ""}[r["met"]]
        print(f"| {r['target']} | {r['measured']} | {r['goal']} | {status} |")
