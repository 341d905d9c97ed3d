"""Client stubs of the adp.v1 services, made from the descriptors in adp_pb2.

grpcio-tools would generate the same callables (plus server-side classes this client never
uses); reading them from the proto's own descriptor keeps one generated module, adp_pb2, and
makes every method of the proto callable under its proto name.
"""

from . import adp_pb2


class Stub:
    """The client calls of one service of adp.proto on a channel: an attribute per method,
    named as in the proto (`Stub(channel, "Control").Register(request, timeout=...)`).

    Thread safety: as grpc's multi-callables, which may be called from any thread.
    """

    def __init__(self, channel, service: str):
        desc = adp_pb2.DESCRIPTOR.services_by_name.get(service)
        if desc is None:
            known = ", ".join(sorted(adp_pb2.DESCRIPTOR.services_by_name))
            raise ValueError(f"adp.proto has no service {service!r} (it has {known})")
        # The channel's call factory for each (client streams, server streams) kind.
        factories = {
            (False, False): channel.unary_unary,
            (True, False): channel.stream_unary,
            (False, True): channel.unary_stream,
            (True, True): channel.stream_stream,
        }
        for method in desc.methods:
            make = factories[(method.client_streaming, method.server_streaming)]
            request = getattr(adp_pb2, method.input_type.name)
            response = getattr(adp_pb2, method.output_type.name)
            call = make(
                f"/{desc.full_name}/{method.name}",
                request_serializer=request.SerializeToString,
                response_deserializer=response.FromString,
            )
            setattr(self, method.name, call)
