"""The names every command module imports, gathered in one place.

Each lives in a module with one job: :mod:`._settings` (options, exit codes,
CliError), :mod:`._params` (argument types), :mod:`._console` (output),
:mod:`._prompt` (the [y/N] question), :mod:`._errors` (library errors in a
person's words), :mod:`._paths` (files checked before the line is touched),
:mod:`._runner` (running a command, the port rule for writes).
"""

from __future__ import annotations

from ..units import current_text, temperature_text
from ._console import (
    current_json,
    emit_json,
    err,
    fail,
    fmt_degrees,
    id_ranges,
    ids_named,
    ids_text,
    no_servo_among,
    out,
    temperature_json,
)
from ._errors import (
    NO_REPLY_HINTS,
    NobodyAnswered,
    answered_garbled,
    no_reply_error,
    none_of_them_answered,
    nothing_answered,
    translate,
)
from ._loop import run_loop
from ._params import (
    ALL_BAUDS,
    BAUD_LIST,
    ID_LIST,
    SERVO_ID,
    ListType,
    NegativeNumbersCommand,
    ServoIdType,
    all_ids_option,
    choice_option,
    every_id,
    json_option,
    seconds_option,
    yes_option,
)
from ._paths import check_backup_path, check_input_path, check_line_files, check_output_path
from ._prompt import ask_yes_no, confirm
from ._runner import advise, note_simulator, require_port, run
from ._settings import DEFAULT_PORT, CliError, ExitCode, Settings, settings_of, setup_logging

__all__ = [
    "ALL_BAUDS",
    "BAUD_LIST",
    "DEFAULT_PORT",
    "ID_LIST",
    "NO_REPLY_HINTS",
    "SERVO_ID",
    "CliError",
    "ExitCode",
    "ListType",
    "ServoIdType",
    "Settings",
    "NegativeNumbersCommand",
    "advise",
    "all_ids_option",
    "answered_garbled",
    "ask_yes_no",
    "check_backup_path",
    "check_input_path",
    "check_line_files",
    "check_output_path",
    "choice_option",
    "confirm",
    "current_json",
    "current_text",
    "emit_json",
    "every_id",
    "err",
    "fail",
    "fmt_degrees",
    "id_ranges",
    "ids_named",
    "ids_text",
    "json_option",
    "no_reply_error",
    "no_servo_among",
    "note_simulator",
    "none_of_them_answered",
    "nothing_answered",
    "NobodyAnswered",
    "out",
    "require_port",
    "run",
    "run_loop",
    "seconds_option",
    "settings_of",
    "setup_logging",
    "temperature_json",
    "temperature_text",
    "translate",
    "yes_option",
]
