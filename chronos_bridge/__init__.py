"""Chronos car Wi-Fi link: the Protocol Buffers wire format, the host-side conversion of car
packets into the suite's measurement stream, and the car-side encoders an emulator needs.

Modules (import what you need; this package imports nothing eagerly):

- :mod:`chronos_bridge.proto` -- the ``.proto`` files and the checked-in generated code.
- :mod:`chronos_bridge.codec` -- datagram bytes <-> validated packets, both directions.
- :mod:`chronos_bridge.car_state` -- ``CarState`` -> measurements + telemetry (host side), and
  simulator values -> raw firmware values (car side, for the emulator).

The wire format is ``shared/specs/chronos-wifi-protocol.md``.
"""

#: Default UDP port on host and car.
DEFAULT_PORT = 20211
