"""The ``[hlc.autopilot_params]`` of the ``px4`` adapter: the MAVLink adapter's, with PX4's defaults and checks.

Link, identity, signing, timeouts and the set-point limits are the same keys as the ``mavlink``
adapter's (docs/ardupilot.md's table); docs/px4.md lists what differs. ArduCopter's GUID_TIMEOUT limit
(``max_guid_timeout``) has no meaning here and is refused when given.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from antalate_lcm.vehicles.kit.params import defaults
from antalate_lcm.vehicles.mavlink.params import Params


class Px4Params(Params):
    """`Params` with PX4's defaults: the offboard link of SITL instance 0, set-points streamed at 10 Hz."""

    # PX4 SITL instance N sends its offboard link to udpin:127.0.0.1:(14540+N)
    connection: str = "udpin:127.0.0.1:14540"
    # rate of the OFFBOARD set-point stream (PX4 needs >= 2 Hz, COM_OF_LOSS_T)
    velocity_resend_hz: float = Field(10.0, ge=2.0, le=50.0)
    # s the set-point stream runs before the adapter asks PX4 for OFFBOARD
    offboard_lead: float = Field(1.0, ge=0.2, le=5.0)
    # largest COM_OF_LOSS_T (s) the pre-flight check accepts
    max_offboard_loss_timeout: float = Field(1.0, gt=0, le=5.0)

    @model_validator(mode="after")
    def _no_arducopter_keys(self) -> Px4Params:
        if "max_guid_timeout" in self.model_fields_set:
            raise ValueError(
                "max_guid_timeout is ArduCopter's GUID_TIMEOUT check; PX4's is max_offboard_loss_timeout"
            )
        return self


#: Defaults by name (tools and docs checks).
PX4_DEFAULTS = defaults(Px4Params)
