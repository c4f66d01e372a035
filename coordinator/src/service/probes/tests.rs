use std::time::Duration;

use tessera_proto::v1 as pb;
use tonic::transport::Channel;
use tonic::{Code, Request};
use tonic_health::pb::health_check_response::ServingStatus as Wire;
use tonic_health::pb::health_client::HealthClient;
use tonic_health::pb::HealthCheckRequest;
use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
use tonic_reflection::pb::{v1, v1alpha};

use crate::service::{Auth, CoordinatorService, Role, Timing, Tokens};

const ADMIN: &str = "0123456789abcdef0123";

/// A coordinator with one admin token, served on loopback; its channel.
async fn serve() -> (CoordinatorService, Channel) {
    let tokens = Tokens::new().with(Role::Admin, "root", ADMIN);
    let service = CoordinatorService::new(Timing::default()).with_auth(Auth::new(Some(tokens), false));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let routes = service.clone().into_server();
    tokio::spawn(
        crate::service::server().add_routes(routes).serve_with_incoming(crate::service::incoming(listener)),
    );
    let channel = Channel::from_shared(url).unwrap().connect().await.unwrap();
    (service, channel)
}

async fn health(channel: &Channel, service: &str) -> Result<Wire, tonic::Status> {
    let r = HealthClient::new(channel.clone()).check(HealthCheckRequest { service: service.into() }).await?;
    Ok(r.into_inner().status())
}

#[tokio::test]
async fn health_answers_without_a_token_and_turns_not_serving_at_shutdown() {
    let (service, channel) = serve().await;
    for name in ["", "tessera.v1.Coordinator", "tessera.v1.Workers"] {
        assert_eq!(health(&channel, name).await.unwrap(), Wire::Serving, "{name:?}");
    }
    assert_eq!(health(&channel, "tessera.v1.Nothing").await.unwrap_err().code(), Code::NotFound);
    service.shutdown();
    for name in ["", "tessera.v1.Coordinator", "tessera.v1.Workers"] {
        let mut tries = 0;
        while health(&channel, name).await.unwrap() != Wire::NotServing {
            tries += 1;
            assert!(tries < 200, "{name:?} still serving 2 s after shutdown");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }
}

#[tokio::test]
async fn tessera_calls_still_need_a_token() {
    let (_service, channel) = serve().await;
    let mut client = pb::coordinator_client::CoordinatorClient::new(channel.clone());
    let refused = client.status(pb::StatusRequest { job_id: 0 }).await.unwrap_err();
    assert_eq!(refused.code(), Code::Unauthenticated, "{refused:?}");
    let mut with_token = Request::new(pb::StatusRequest { job_id: 0 });
    with_token.metadata_mut().insert("authorization", format!("Bearer {ADMIN}").parse().unwrap());
    client.status(with_token).await.unwrap();
    // Paths that merely start or end like an open service reach nothing open.
    for path in [
        "/grpc.health.v1.Health/../tessera.v1.Coordinator/Status",
        "/grpc.health.v1.Health.tessera.v1.Coordinator/Status",
        "/grpc.health.v1/tessera.v1.Coordinator/Status",
        "/tessera.v1.Coordinator/Status/grpc.health.v1.Health/Check",
        "//tessera.v1.Coordinator/Status",
    ] {
        let mut grpc = tonic::client::Grpc::new(channel.clone());
        grpc.ready().await.unwrap();
        let codec = tonic_prost::ProstCodec::<pb::StatusRequest, pb::StatusResponse>::default();
        let r = grpc
            .unary(Request::new(pb::StatusRequest { job_id: 0 }), path.parse().unwrap(), codec)
            .await
            .unwrap_err();
        assert!(matches!(r.code(), Code::Unimplemented | Code::Unauthenticated), "{path}: {r:?}");
    }
}

fn list_request() -> v1::ServerReflectionRequest {
    v1::ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    }
}

#[tokio::test]
async fn reflection_lists_every_service_without_a_token_in_both_versions() {
    let (_service, channel) = serve().await;
    let want = [
        "grpc.health.v1.Health",
        "grpc.reflection.v1.ServerReflection",
        "grpc.reflection.v1alpha.ServerReflection",
        "tessera.v1.Coordinator",
        "tessera.v1.Workers",
    ];
    let mut v1_client = v1::server_reflection_client::ServerReflectionClient::new(channel.clone());
    let mut answers =
        v1_client.server_reflection_info(tokio_stream::iter([list_request()])).await.unwrap().into_inner();
    let Some(MessageResponse::ListServicesResponse(list)) =
        answers.message().await.unwrap().unwrap().message_response
    else {
        panic!("v1 answered a list with something else")
    };
    let mut names: Vec<_> = list.service.into_iter().map(|s| s.name).collect();
    names.sort();
    assert_eq!(names, want);

    let mut alpha = v1alpha::server_reflection_client::ServerReflectionClient::new(channel);
    let ask = v1alpha::ServerReflectionRequest {
        host: String::new(),
        message_request: Some(v1alpha::server_reflection_request::MessageRequest::FileContainingSymbol(
            "tessera.v1.Coordinator".into(),
        )),
    };
    let mut answers = alpha.server_reflection_info(tokio_stream::iter([ask])).await.unwrap().into_inner();
    let Some(v1alpha::server_reflection_response::MessageResponse::FileDescriptorResponse(files)) =
        answers.message().await.unwrap().unwrap().message_response
    else {
        panic!("v1alpha answered a symbol with something else")
    };
    use prost::Message as _;
    let file = prost_types::FileDescriptorProto::decode(files.file_descriptor_proto[0].as_slice()).unwrap();
    assert_eq!(file.package(), "tessera.v1");
    let coordinator = file.service.iter().find(|s| s.name() == "Coordinator").unwrap();
    assert!(coordinator.method.iter().any(|m| m.name() == "Status"), "{coordinator:?}");
}

#[test]
fn the_descriptor_sets_build_both_reflection_versions() {
    // The `expect`s of `reflection_v1`/`_v1alpha` hold for the sets built into the binary.
    super::reflection().build_v1().unwrap();
    super::reflection().build_v1alpha().unwrap();
}

#[tokio::test]
async fn the_health_listener_serves_health_and_nothing_else() {
    let service = CoordinatorService::new(Timing::default());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let routes = service.health_routes();
    tokio::spawn(
        crate::service::server().add_routes(routes).serve_with_incoming(crate::service::incoming(listener)),
    );
    let channel = Channel::from_shared(url).unwrap().connect().await.unwrap();
    assert_eq!(health(&channel, "tessera.v1.Coordinator").await.unwrap(), Wire::Serving);
    // An open coordinator would answer anyone: here there is no Coordinator at all.
    let mut client = pb::coordinator_client::CoordinatorClient::new(channel.clone());
    assert_eq!(client.status(pb::StatusRequest { job_id: 0 }).await.unwrap_err().code(), Code::Unimplemented);
    let mut reflection = v1::server_reflection_client::ServerReflectionClient::new(channel.clone());
    let r = reflection.server_reflection_info(tokio_stream::iter([list_request()])).await;
    assert_eq!(r.unwrap_err().code(), Code::Unimplemented);
    service.shutdown();
    let mut tries = 0;
    while health(&channel, "").await.unwrap() != Wire::NotServing {
        tries += 1;
        assert!(tries < 200, "still serving 2 s after shutdown");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}
