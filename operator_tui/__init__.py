"""The antalate operator console: a Textual app that is an LCM node on the LAN bus."""
