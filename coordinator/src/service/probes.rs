//! The standard gRPC services that probes and generic tools call without a token: health
//! (`grpc.health.v1.Health`) and server reflection (`grpc.reflection.v1` and `v1alpha`).
//!
//! They stand beside the Tessera services in the router, not behind the token interceptor:
//! tonic routes a call by its service's exact path (`/grpc.health.v1.Health/Check`), so
//! only these services' methods are open, and every `tessera.v1` call still goes through
//! `auth::Authenticate`. Health tells nothing beyond "serving"; reflection tells only the
//! public schema (`tessera.proto` is published with the source). Their requests are a name
//! or a symbol, so their decode limit is the small one of every non-submit call.
//! `docs/security/connections.md` gives the reasoning.

use tessera_proto::v1::coordinator_server::CoordinatorServer;
use tessera_proto::v1::workers_server::WorkersServer;
use tonic::server::NamedService;
use tonic::service::Routes;
use tonic_health::pb::health_server::{Health, HealthServer};
use tonic_health::ServingStatus;

use super::CoordinatorService;

/// The services whose health is reported, besides the server as a whole (`""`).
pub const HEALTH_SERVICES: [&str; 2] = [
    <CoordinatorServer<CoordinatorService> as NamedService>::NAME,
    <WorkersServer<CoordinatorService> as NamedService>::NAME,
];

/// The largest health or reflection request decoded (a service name or a symbol).
const MAX_PROBE_REQUEST_BYTES: usize = super::gate::MAX_REQUEST_BYTES;

/// `routes` with the health and reflection services added. Must be called within a
/// Tokio runtime (see [`health`]).
pub(super) fn add(routes: Routes, service: &CoordinatorService) -> Routes {
    routes
        .add_service(health(service))
        .add_service(reflection_v1().max_decoding_message_size(MAX_PROBE_REQUEST_BYTES))
        .add_service(reflection_v1alpha().max_decoding_message_size(MAX_PROBE_REQUEST_BYTES))
}

impl CoordinatorService {
    /// The health service alone, for a plain-text listener of its own (`coordinator
    /// --health-listen`): Kubernetes' `grpc` probe speaks no TLS, and health tells nothing
    /// but whether the coordinator serves. Must be called within a Tokio runtime.
    pub fn health_routes(&self) -> Routes {
        Routes::new(health(self))
    }
}

/// The health service: SERVING for `""` and every name in `HEALTH_SERVICES` from the
/// start, NOT_SERVING for all of them once `service` shuts down (a task spawned here
/// watches for it, so this needs a Tokio runtime).
fn health(service: &CoordinatorService) -> HealthServer<impl Health> {
    let (reporter, health) = tonic_health::server::health_reporter();
    // Set before the server answers, so that no probe sees a service as unknown; the lock
    // of a reporter just made is free, so this completes at once.
    futures_executor::block_on(async {
        for name in HEALTH_SERVICES {
            reporter.set_service_status(name, ServingStatus::Serving).await;
        }
    });
    let mut stop = service.shutting_down();
    tokio::spawn(async move {
        // Err: the service is gone, and with it anything that could serve.
        let _ = stop.wait_for(|down| *down).await;
        for name in std::iter::once("").chain(HEALTH_SERVICES) {
            reporter.set_service_status(name, ServingStatus::NotServing).await;
        }
    });
    health.max_decoding_message_size(MAX_PROBE_REQUEST_BYTES)
}

/// The descriptor sets reflection serves: Tessera's, health's, and both reflection
/// versions' (so that either version lists the same services).
fn reflection() -> tonic_reflection::server::Builder<'static> {
    tonic_reflection::server::Builder::configure()
        .include_reflection_service(false)
        .register_encoded_file_descriptor_set(tessera_proto::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_reflection::pb::v1::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_reflection::pb::v1alpha::FILE_DESCRIPTOR_SET)
}

// The descriptor sets are compiled into the binary and decoded by the tests below, so
// building from them cannot fail at run time.
fn reflection_v1() -> tonic_reflection::pb::v1::server_reflection_server::ServerReflectionServer<
    impl tonic_reflection::pb::v1::server_reflection_server::ServerReflection,
> {
    reflection().build_v1().expect("the descriptor sets built into this binary decode")
}

fn reflection_v1alpha() -> tonic_reflection::pb::v1alpha::server_reflection_server::ServerReflectionServer<
    impl tonic_reflection::pb::v1alpha::server_reflection_server::ServerReflection,
> {
    reflection().build_v1alpha().expect("the descriptor sets built into this binary decode")
}

#[cfg(test)]
mod tests;
