"""The one ritad config template of the tests and benchmarks: a TOML text from a few choices.

``@TMP@`` stands for the temp dir ``fakes.launch.start_ritad`` runs in (it replaces it);
pass real paths to write the file yourself.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

#: every device simulated (the fakes' world)
SIM_DEVICES: dict[str, str] = {"camera": "sim:", "tracker": "sim:", "robot": "sim:"}
#: devices that never connect: the bus alone (security, refusals)
NO_DEVICES: dict[str, str] = {"camera": "genicam:///nonexistent/producer.cti",
                              "tracker": "emscon://127.0.0.1:1", "robot": "loop://"}
#: the three ipc sockets' names in ``ipc_dir``
IPC_NAMES = {"command": "cmd", "telemetry": "telemetry", "frame": "frames"}


def ritad_toml(*, ipc_dir: str | Path | None = "@TMP@/rt", tcp: bool = False, data: str | Path = "@TMP@/data",
               devices: Mapping[str, str] | None = None, worker: bool = False, seed: int | None = None,
               curve: bool = False, insecure_tcp: bool = False, log_level: str | None = None) -> str:
    """ritad's config: ipc endpoints in ``ipc_dir`` (None: no ipc), with ``tcp`` also 127.0.0.1 port 0,
    data in ``data``; ``devices`` replace entries of :data:`SIM_DEVICES`; ``seed`` the simulated world's."""
    lines = ["[daemon]"]
    for kind, name in IPC_NAMES.items():
        eps = (([f"ipc://{ipc_dir}/{name}"] if ipc_dir is not None else [])
               + (["tcp://127.0.0.1:0"] if tcp else []))
        lines.append(f"{kind}_endpoints = {json.dumps(eps)}")  # a JSON list of plain strings is TOML
    lines += [f'data_dir = "{data}"', f"start_worker = {str(worker).lower()}"]
    if log_level:
        lines.append(f'log_level = "{log_level}"')
    lines += ["[devices]", *(f'{k} = "{v}"' for k, v in {**SIM_DEVICES, **(devices or {})}.items())]
    if seed is not None:
        lines += ["[sim]", f"seed = {seed}"]
    if curve or insecure_tcp:
        lines += ["[security]", *(["curve = true"] if curve else []),
                  *(["insecure_tcp = true"] if insecure_tcp else [])]
    return "\n".join(lines) + "\n"


def ipc_command(ipc_dir: str | Path) -> str:
    """The command endpoint :func:`ritad_toml` puts in ``ipc_dir``."""
    return f"ipc://{ipc_dir}/{IPC_NAMES['command']}"


__all__ = ["IPC_NAMES", "NO_DEVICES", "SIM_DEVICES", "ipc_command", "ritad_toml"]
