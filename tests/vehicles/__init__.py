"""The vehicle adapters (simulator, Tello, MAVLink, PX4, Crazyflie), their links and the protocol
emulators they are tested against.

Moved here from the flat tests/ by retest.py (issue 26).
"""
