"""``peer_sensor``: a simulated sensor of nearby peers (range, bearing, relative velocity), pure ``logic``
and its plugin ``behavior`` (docs/behaviors.md, "Sensing peers")."""
