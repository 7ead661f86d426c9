"""The line's policies: finding servos, telling why one did not answer, renumbering the only one, changing an
EEPROM safely, reading positions without freeing what may not go limp, freeing every servo there, bringing a
servo into a loop's targets from where it stands.

They need no bus, only a line's small protocol (:class:`ics35_async.line.Line`, which the bus
offers), so library users get the same rules the ``ics35`` command follows.
"""

from __future__ import annotations

from .blend_in import BlendIn, Joining, probe_position_reads
from .eeprom_write import (
    POWER_UP_PARAMS,
    EepromPlan,
    EepromWriteResult,
    ServoWriteReport,
    WriteOutcome,
    check_changes,
    edit_image,
    plan_eeprom_write,
    power_up_note,
    write_eeprom_plan,
    write_eeprom_plans,
)
from .failure_kinds import (
    Line,
    LineOpener,
    answers_short_read,
    echo_setting_wrong,
    id0_top_bit_differs,
    nothing_came_back,
    reopening,
)
from .free import FreeReport, free_servos
from .held_check import HELD_SLACK_DEGREES, off_its_way
from .id_write import (
    IdChange,
    IdSurvey,
    Refusal,
    cut_short_words,
    look_elsewhere,
    survey_for_id_write,
    write_lone_id,
)
from .no_reply import NoReply, NoReplyCause, why_no_reply
from .position_read import (
    NO_READ_ICS35,
    PositionReading,
    StreamPlan,
    plan_position_stream,
    read_position_without_freeing,
)
from .scan import (
    ALL_BAUDS,
    ALL_IDS,
    RateScan,
    RateSearch,
    ScanReport,
    anyone_there,
    check_other_ids,
    device_rates,
    other_bauds,
    probe_ids,
    scan,
    search_other_rates,
    servo_rates,
    trying_rate,
)
from .scan_units import FoundServo, read_eeprom_agreed

__all__ = [
    "id0_top_bit_differs",
    "answers_short_read",
    "ALL_BAUDS",
    "ALL_IDS",
    "BlendIn",
    "NO_READ_ICS35",
    "POWER_UP_PARAMS",
    "EepromPlan",
    "EepromWriteResult",
    "FoundServo",
    "FreeReport",
    "IdChange",
    "IdSurvey",
    "Joining",
    "Line",
    "LineOpener",
    "NoReply",
    "NoReplyCause",
    "PositionReading",
    "RateScan",
    "RateSearch",
    "Refusal",
    "ScanReport",
    "StreamPlan",
    "ServoWriteReport",
    "WriteOutcome",
    "anyone_there",
    "check_changes",
    "check_other_ids",
    "device_rates",
    "other_bauds",
    "echo_setting_wrong",
    "edit_image",
    "free_servos",
    "HELD_SLACK_DEGREES",
    "off_its_way",
    "look_elsewhere",
    "cut_short_words",
    "nothing_came_back",
    "plan_eeprom_write",
    "plan_position_stream",
    "power_up_note",
    "probe_ids",
    "probe_position_reads",
    "read_position_without_freeing",
    "reopening",
    "read_eeprom_agreed",
    "scan",
    "search_other_rates",
    "servo_rates",
    "survey_for_id_write",
    "trying_rate",
    "write_eeprom_plan",
    "write_eeprom_plans",
    "why_no_reply",
    "write_lone_id",
]
