"""A generic gRPC client that knows nothing of terl's protos: it discovers them by reflection.

Usage: reflection_client.py HOST:PORT SERVICE STATUS_METHOD STATUS_RESPONSE_TYPE
Prints one JSON object with what it found; the Rust test (tests/grpc.rs) checks it.

grpcio-reflection ships only the v1alpha protos. grpc.reflection.v1 has the same messages with
the same field numbers, so v1 is exercised by sending those messages to the v1 method path.
"""

import json
import sys

import grpc
from google.protobuf import descriptor_pool, message_factory
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection_pb2
from grpc_reflection.v1alpha.proto_reflection_descriptor_database import (
    ProtoReflectionDescriptorDatabase,
)


def list_services(channel, version):
    call = channel.stream_stream(
        f"/grpc.reflection.{version}.ServerReflection/ServerReflectionInfo",
        request_serializer=reflection_pb2.ServerReflectionRequest.SerializeToString,
        response_deserializer=reflection_pb2.ServerReflectionResponse.FromString,
    )
    request = reflection_pb2.ServerReflectionRequest(list_services="")
    (response,) = list(call(iter([request]), timeout=10))
    if response.HasField("error_response"):
        raise RuntimeError(f"{version}: {response.error_response.error_message}")
    return sorted(s.name for s in response.list_services_response.service)


def main():
    addr, service, method, response_type = sys.argv[1:5]
    channel = grpc.insecure_channel(addr)
    grpc.channel_ready_future(channel).result(timeout=10)

    # v1alpha through the library's own descriptor database.
    database = ProtoReflectionDescriptorDatabase(channel)
    pool = descriptor_pool.DescriptorPool(database)
    service_descriptor = pool.FindServiceByName(service)
    method_descriptor = service_descriptor.FindMethodByName(method)

    # Call the status method with message classes built from reflected descriptors only.
    request_class = message_factory.GetMessageClass(method_descriptor.input_type)
    response_class = message_factory.GetMessageClass(pool.FindMessageTypeByName(response_type))
    status = channel.unary_unary(
        f"/{service}/{method}",
        request_serializer=request_class.SerializeToString,
        response_deserializer=response_class.FromString,
    )(request_class(), timeout=10)

    health = health_pb2_grpc.HealthStub(channel)
    serving = {}
    for name in ["", service]:
        reply = health.Check(health_pb2.HealthCheckRequest(service=name), timeout=10)
        serving[name] = health_pb2.HealthCheckResponse.ServingStatus.Name(reply.status)

    print(
        json.dumps(
            {
                "v1alpha_services": sorted(database.get_services()),
                "v1_services": list_services(channel, "v1"),
                "v1alpha_listed": list_services(channel, "v1alpha"),
                "methods": sorted(m.name for m in service_descriptor.methods),
                "status_run_id": status.run_id,
                "health": serving,
            }
        )
    )


if __name__ == "__main__":
    main()
