"""Names vulture reports as unused in antalate_lcm, operator_tui and behaviors that are used after all.

`vulture` (configured in pyproject's [tool.vulture]) reads this file with the packages: a name written
here counts as used. Every entry says who uses it, because vulture cannot see them: frameworks that call
by name, entry points, pydantic fields read by key, foreign objects we set attributes on, and the tests,
tools and documentation that use a public name. Framework hooks matched by pattern (Textual ``on_*`` /
``action_*``, pydantic validators, FastAPI routes) are in [tool.vulture] instead. Something that is
really unused is removed, not listed here (tests/architecture/test_dead_code.py keeps the list honest).
"""

# ruff: noqa: B018 - a bare name or attribute is how a vulture whitelist marks it used

from vulture.whitelist_utils import Whitelist

_ = Whitelist()

# --- Entry points (pyproject [project.entry-points]): loaded by name through importlib.metadata.
_.AutoOperator
_.DirectionFollow
_.DovratSwarm
_.VideoCapture

# --- Textual reads these class attributes and calls these hooks by name.
_.border_title
_.TITLE
_.ENABLE_COMMAND_PALETTE
_.get_default_screen
_._make_app  # textual-serve's Server hook (operator_tui/web.py overrides it)

# --- Set on objects of other libraries, which read them.
_.should_exit  # uvicorn.Server polls it to stop
_.is_flying  # djitellopy: keeps end()/__del__ from sending a blocking land
_.sign_outgoing  # pymavlink's signing state
_.allow_unsigned_callback  # pymavlink's signing state
_.handle_eof  # pymavlink connection hooks
_.handle_disconnect
_.robust_parsing  # pymavlink's parser option

# --- pydantic fields read by key (model_dump / a mapping), not by attribute.
_.command_ttl
_.pending_commands  # station/_models.py: a field of the JSON the API returns (docs/station-protocol.md)

# --- The firmware's names, kept whole so the decoded bitfield reads like supervisor.h.
_.AUTO_ARMED
_.HL_TRAJ_FINISHED
_.can_be_armed
_.can_fly
_.hl_active
_.hl_disabled

# --- State names the MC's table spells out (the wire-vocabulary work owns these tables).
_.HLC_INIT
_.HLC_TAKEOFF

# --- Public API documented for users' own code and tools (docs/*.md), exercised by the tests.
_.emergency  # Tello extra: docs/tello.md
_.answering  # MemoryLink.answering: docs/ardupilot.md, users' tests without SITL
_.push_state  # tello MemoryLink: the peer's state lines (docs/tello.md, the Tello emulator's memory mode)
_.damaged_datagrams  # Bus: the own udpm reader's drop count beside decode_errors() (docs/lan.md)

# --- cflib's CRTPDriver interface: cflib's link thread and scanner call these on our memory:// driver.
_.needs_resending
_.send_packet
_.receive_packet
_.get_status
_.scan_interface
_.get_help
_.publish_errors  # Bus: docs/wan.md
_.setpoints_withheld  # MavlinkAdapter: docs/ardupilot.md
_.vehicle_findings  # MavlinkAdapter: what the vehicle checks found (docs/ardupilot.md)
_.resending  # MavlinkAdapter: a command is being resent (tests/vehicles/test_mavlink_adapter.py)
_.ready_reasons  # MavlinkAdapter: why arming would be refused (tests/vehicles/test_mavlink_adapter.py)
_.reconnects  # CrazyflieAdapter: link recoveries (tests/vehicles/test_crazyflie_adapter.py)
_.reports_ok  # OscNode: reports the station accepted (tests/agent/test_osc.py)
_.reporting  # OscNode: whether the exchange with the station runs (tests/agent/test_osc.py)
_.set_refuse_arm  # SimAdapter fault knobs for tests and the demo
_.set_time_scale
_.sim_time
_.position_ne  # TelloAdapter dead reckoning (tests/vehicles/test_tello_adapter.py)
_.dead_reckoning_problem  # TelloAdapter: the velocity unit check for tools (tests/vehicles/test_tello_adapter.py)
_.from_wgs84  # crazyflie frames: the inverse, checked round trip (tests/vehicles/test_crazyflie_units.py)
_.block_size  # crazyflie log blocks fit one packet (tests/vehicles/test_crazyflie_units.py)
_.LOG_MAX_BYTES
_.stale_packaged_types  # tools/codegen.py: the bindings-are-current checks (tests/tools/test_types_cmd.py)
_.stale_files  # tests/wire/test_codegen.py
_.wait_stopped  # VideoCapture: tests/vehicles/test_video_capture.py
_.row_count  # AgentTable: tests/console/test_tui.py
_.render_map  # swarm_map's pure renderer: tests/console/test_tui_model.py
_.repaints  # SwarmMap: repaints only on a changed picture (tests/console/test_tui.py)
_.layouts_skipped  # the event log's skipped layouts (tests/console/test_tui.py)
_.Gathering  # entry points (pyproject): the canonical swarm rules and the simulated peer sensor
_.Flocking
_.Dispersion
_.PeerSensor
_.has_velocity  # peer_scan_t field, written by the peer sensor, read by its consumers
_.CONTINUE  # safety.filter.Policy: chosen by value from [safety] no_peers (Policy("continue"))
# --- The import protocol: the deprecated package shim antalate_lcm/autopilot/ (issue #26), its
# finder and loader, called by the import system.
_.find_spec
_.create_module
_.exec_module
# --- Old names kept one release by base.deprecation.renamed_attribute (issue #26): read by users' code.
_.autopilot_state
