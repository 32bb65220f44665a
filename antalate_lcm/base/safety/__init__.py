"""Keeping a swarm apart and inside its fence, below every behavior (docs/safety.md).

Pure logic, no I/O: `filter.SafetyFilter` (the per-agent velocity filter), `separation` (peers as
barrier constraints), `geofence` (the swarm's polygon, floor and ceiling), `barrier` (the small
quadratic programme every constraint goes through). The HLC node wires it in (`antalate_lcm.agent.hlc`).
"""
