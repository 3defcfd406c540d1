"""The suite's topics between machines over Zenoh, in rmw_zenoh's wire format (ROS 2 Jazzy).

:mod:`~ros4crs.zenoh.session` opens a Zenoh session from
:class:`~ros4crs.zenoh.session.ZenohSettings` (router, peer or client; explicit endpoints, no
multicast; a Zenoh configuration file for TLS, authentication and access control).
"""
