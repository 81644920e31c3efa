"""ROS 2 message definitions for the tests that write MCAPs with mcap_ros2 (a definition is
the message's own fields, then each type it uses after a separator line)."""

from __future__ import annotations

SEPARATOR = "=" * 80
#: std_msgs/Header and the builtin_interfaces/Time in it
HEADER = f"""{SEPARATOR}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{SEPARATOR}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def stamped(fields: str, *more: str) -> str:
    """The definition of a message with a ``std_msgs/Header header`` and ``fields``
    (newline-separated), the Header's types and ``more`` type blocks ("MSG: ...\\n...")."""
    return (
        "std_msgs/Header header\n"
        + fields.strip()
        + "\n"
        + HEADER
        + "".join(f"{SEPARATOR}\n{m.strip()}\n" for m in more)
    )
