"""The bus library every program shares: protocol, client, keys, atomic files, dataset schemas."""
from __future__ import annotations

from daemon.face import lazy_face

#: the package's public names -> the module that defines them; imported on first use, so
#: importing one submodule (or this face) never loads the rest
_FACE = {
    "Client": "client",
    "ClientTimeout": "client",
    "ClientRefused": "client",
    "Subscriber": "client",
    "default_endpoint": "client",
    "CommandError": "protocol",
    "ErrorCode": "protocol",
    "SCHEMA_VERSION": "protocol",
    "COMMANDS": "command_table",
    "Command": "command_table",
    "validate": "command_table",
    "Arg": "args",
    "BadValue": "args",
    "Procedure": "procedures",
    "PROCEDURES": "procedures",
    "Kind": "names",
    "Role": "names",
    "Topic": "names",
    "KINDS": "names",
    "ROLES": "names",
    "atomic_write_bytes": "storage",
    "atomic_write_json": "storage",
    "atomic_write_text": "storage",
    "Dataset": "storage",
    "read_results": "storage",
    "DatasetInvalid": "datasets",
    "validate_folder": "datasets",
    "STATION_FILE": "station",
}
__all__, __getattr__ = lazy_face(__name__, _FACE)
