"""Protocol emulators (Tello SDK, ArduCopter MAVLink, Crazyflie CRTP) that tests drive through the real
client libraries; ``lifecycle`` is what they share (threads, context manager, snapshots)."""
