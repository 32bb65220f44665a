"""The helpers every test leans on, in one place (tests/README.md, "The harness").

``netns``: private network namespaces (`NetNamespace`, its modes, `require_netns`, `private_netns`,
`run_unrouted`, JSON-lines peers inside with `NetNamespace.peer`); ``process``: the ``antalate``
command (`run_antalate`, `antalate_argv`), a child's environment, reading its output lines as they come
(`OutputLines`) and stopping its whole process group; ``polling``: the one `wait_for`; ``jsonl``: both
sides of a JSON-lines child; ``agents``: the one config builder (`agent_config`, `swarm_config`) and the
agent runner across processes (`AgentProcesses`); ``inprocess``: the runner of nodes in the test's own
process (`InProcess`); ``timeline``: the event timeline of a child that reports JSON lines;
``bma``: the BMA's in-process `Harness` and the behaviors tests name in configs; ``memory_agent``: a
whole agent in the test's process; ``cases``: refusal tables kept as TOML; ``clock``: `FakeClock`;
``lifecycle``: `Started`, a set-up that closes what it started when its start fails; ``messages``:
messages put on a bus by hand; ``synthetic_logs``: LCM logs of made-up flights; ``lcm_tables``:
lcm-gen's field tables, typed; ``tmux``, ``tls``, ``wheel_support``: a real terminal, a throw-away CA,
the wheel as a user builds it; ``scheduling``: the suite's order under xdist (``module_times.json``).

``tests.polling`` and ``tests.bma_support``, which docs/behaviors.md once showed, still import the same
names for one release, with a DeprecationWarning.
"""
