#!/usr/bin/env python3
"""A third-party gRPC client of a Tessera coordinator, knowing nothing of tessera.proto.

    grpc_reflect.py HOST:PORT TOKEN_FILE
    grpc_reflect.py --health-only HOST:PORT

Checks the standard health service (no token), lists the services through server
reflection (no token), then calls tessera.v1.Coordinator/Status with message classes built
from the descriptors that reflection returned, once without the token (which must be
refused) and once with it as `authorization: Bearer ...` metadata, and prints the jobs and
workers, one line each. With --health-only (the coordinator's --health-listen port):
health SERVING, and reflection not served there. Exits non-zero, saying why, on anything unexpected. Uses grpcio,
grpcio-health-checking and grpcio-reflection (tests/tools/grpc-requirements.txt).
"""

import sys

import grpc
from google.protobuf import descriptor_pool, message_factory
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha.proto_reflection_descriptor_database import (
    ProtoReflectionDescriptorDatabase,
)

HEALTH_NAMES = ["", "tessera.v1.Coordinator", "tessera.v1.Workers"]


def fail(what):
    print(f"grpc_reflect.py: {what}", file=sys.stderr)
    sys.exit(1)


def describe(message):
    """`name=value` for each field set, enums by their names: read from the descriptor."""
    parts = []
    for field, value in message.ListFields():
        if field.enum_type is not None:
            value = field.enum_type.values_by_number[value].name
        parts.append(f"{field.name}={value}")
    return " ".join(parts)


def connect(address):
    channel = grpc.insecure_channel(address)
    try:
        grpc.channel_ready_future(channel).result(timeout=10)
    except grpc.FutureTimeoutError:
        fail(f"no connection to {address} within 10 s")
    return channel


def check_health(channel):
    health = health_pb2_grpc.HealthStub(channel)
    for name in HEALTH_NAMES:
        answer = health.Check(health_pb2.HealthCheckRequest(service=name), timeout=10)
        status = health_pb2.HealthCheckResponse.ServingStatus.Name(answer.status)
        print(f"health {name or '(server)'}: {status}")


def health_only(address):
    channel = connect(address)
    check_health(channel)
    try:
        ProtoReflectionDescriptorDatabase(channel).get_services()
        fail("the health listener answers reflection")
    except grpc.RpcError as refused:
        print(f"reflection: {refused.code().name}")


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--health-only":
        return health_only(sys.argv[2])
    if len(sys.argv) != 3:
        fail("usage: grpc_reflect.py HOST:PORT TOKEN_FILE | --health-only HOST:PORT")
    address, token_file = sys.argv[1:]
    with open(token_file, encoding="utf-8") as f:
        token = f.read().strip()
    channel = connect(address)
    check_health(channel)

    reflection = ProtoReflectionDescriptorDatabase(channel)
    for service in sorted(reflection.get_services()):
        print(f"service {service}")

    # Everything below comes from the descriptors reflection sent: no generated code.
    pool = descriptor_pool.DescriptorPool(reflection)
    method = pool.FindServiceByName("tessera.v1.Coordinator").methods_by_name["Status"]
    request_class = message_factory.GetMessageClass(method.input_type)
    response_class = message_factory.GetMessageClass(method.output_type)
    status = channel.unary_unary(
        f"/{method.containing_service.full_name}/{method.name}",
        request_serializer=request_class.SerializeToString,
        response_deserializer=response_class.FromString,
    )
    try:
        status(request_class(), timeout=10)
        fail("Status without a token was answered")
    except grpc.RpcError as refused:
        print(f"status without token: {refused.code().name}")
    answer = status(request_class(), metadata=[("authorization", f"Bearer {token}")], timeout=10)
    print(f"status: {len(answer.jobs)} jobs, {len(answer.workers)} workers")
    for job in answer.jobs:
        print(f"job {describe(job)}")
    for worker in answer.workers:
        print(f"worker {describe(worker)}")


if __name__ == "__main__":
    main()
