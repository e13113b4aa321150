"""The coordinator's gRPC edge: the only part of the coordinator that imports grpc.

One module per concern: the messages of each service (``node_messages``, ``control_messages``,
``image_parts`` for an operator's image in parts, ``frame_packets`` for the Frames stream with its
cache of encoded contents), the services (``node_service``, ``control_service``,
``content_service``, with ``handshake_service`` shared by the first two), how a call is read and
refused (``calls``: the status code of each refusal kind), the budget before authentication
(``admission_interceptor``), the server (``serve``) and the room camera's client
(``room_camera``). The services see the coordinator through :class:`coordinator.ports.ServiceRig`.
"""
