"""The node's ``diagnostic_msgs/DiagnosticArray``."""
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue


def diagnostic_array(stamp, name, hardware_id, level, message, values):
    """``DiagnosticArray`` with one status; ``values`` is ``{key: value}`` (str() each)."""
    status = DiagnosticStatus(
        level=level, name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=str(v)) for k, v in values.items()])
    array = DiagnosticArray(status=[status])
    array.header.stamp = stamp
    return array
