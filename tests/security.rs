//! End-to-end: TLS and authentication with real `tessera` processes on loopback. Certificates
//! come from `tessera certs`, tokens from a tokens file. A TLS farm renders the bytes of a
//! local render; every refused call is refused with the right code and changes nothing
//! (the job list, the images and the database are compared before and after).
//!
//! The parts, in `tests/security/`: `secrets` (a farm's certificates and tokens, and the
//! coordinators and clients using them), `tls` (farms over TLS, with tokens or client
//! certificates, and the certificates themselves), `refusals` (refused calls change
//! nothing; the rules a coordinator and a worker refuse to start or go on with) and
//! `local` (`tessera render`'s own secret). One test binary: each file in `tests/` costs a
//! link.

mod common;

#[path = "security/local.rs"]
mod local;
#[path = "security/refusals.rs"]
mod refusals;
#[path = "security/secrets.rs"]
mod secrets;
#[path = "security/tls.rs"]
mod tls;
