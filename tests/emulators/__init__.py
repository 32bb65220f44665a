"""Protocol emulators (Tello SDK, ArduCopter MAVLink) that tests drive through the real client libraries."""
