//! Who is calling, and what they may do.
//!
//! Every call is authenticated before its message is even decoded: `Authenticate`, the
//! server's interceptor, turns a bearer token (`authorization: Bearer …`, looked up in
//! constant time) or a verified client certificate into a `Principal` and puts it in the
//! request's extensions, or refuses the call with `UNAUTHENTICATED`. Each RPC then asks
//! `require` for its role, and the client RPCs check that a submitter's job is its own,
//! before anything else happens (`PERMISSION_DENIED`). With no tokens and no client
//! certificates (`Auth::open`, in-process uses and loopback coordinators), every caller is
//! the admin `anonymous`.
//!
//! The roles: an admin may do everything; a submitter submits (up to a priority ceiling)
//! and sees and controls only its own jobs; a worker only works; a viewer only reads
//! (Status, Watch, FetchImage).

use std::path::Path;
use std::sync::Arc;

use subtle::{ConditionallySelectable, ConstantTimeEq};
use tessera_description::ids::JobId;
use tonic::{Request, Status};
use tracing::info;

use super::CoordinatorService;

/// What a principal may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Role {
    /// Everything.
    Admin,
    /// Submit, and see and control its own jobs.
    Submitter,
    /// Take batches and return results.
    Worker,
    /// Read: Status, Watch, FetchImage.
    Viewer,
}

impl Role {
    /// Every role, in the order the documentation lists them.
    pub const ALL: [Role; 4] = [Role::Admin, Role::Submitter, Role::Worker, Role::Viewer];

    /// Its name in a tokens file and a certificate's OU.
    pub fn name(self) -> &'static str {
        match self {
            Role::Admin => "admin",
            Role::Submitter => "submitter",
            Role::Worker => "worker",
            Role::Viewer => "viewer",
        }
    }

    /// The role called `name`.
    pub fn parse(name: &str) -> Option<Role> {
        Role::ALL.into_iter().find(|r| r.name() == name)
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Who is calling: a role and a name (the token's, or the client certificate's common
/// name).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Principal {
    /// What it may do.
    pub role: Role,
    /// Its name: a job's owner, a worker's identity.
    pub name: String,
}

/// What a call asks to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Action {
    Submit,
    Status,
    FetchImage,
    Watch,
    Pause,
    Cancel,
    Prioritize,
    Work,
}

impl Action {
    fn name(self) -> &'static str {
        match self {
            Action::Submit => "submit",
            Action::Status => "read the status",
            Action::FetchImage => "fetch images",
            Action::Watch => "watch jobs",
            Action::Pause => "pause or resume jobs",
            Action::Cancel => "cancel jobs",
            Action::Prioritize => "change priorities",
            Action::Work => "work",
        }
    }

    /// The roles allowed to do it.
    fn roles(self) -> &'static [Role] {
        match self {
            Action::Submit | Action::Pause | Action::Cancel | Action::Prioritize => {
                &[Role::Admin, Role::Submitter]
            }
            Action::Status | Action::FetchImage | Action::Watch => {
                &[Role::Admin, Role::Submitter, Role::Viewer]
            }
            Action::Work => &[Role::Admin, Role::Worker],
        }
    }
}

/// Why a tokens file cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AuthError {
    /// It cannot be read.
    #[error("cannot read the tokens file {path}: {reason}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        reason: String,
    },
    /// Every user of the machine can read it.
    #[error("the tokens file {path} can be read by every user (mode {mode:03o}); `chmod 600` it")]
    Exposed {
        /// The file.
        path: String,
        /// Its permission bits.
        mode: u32,
    },
    /// A line is wrong.
    #[error("{path}:{line}: {reason}")]
    Line {
        /// The file.
        path: String,
        /// The line, from 1.
        line: usize,
        /// What is wrong.
        reason: String,
    },
}

/// The shortest token accepted: 16 characters of a generated token carry at least 64 bits.
pub const MIN_TOKEN_CHARS: usize = 16;
/// The longest principal name.
const MAX_NAME_CHARS: usize = 64;

/// The tokens a coordinator knows, each for a role and a name. Only their BLAKE3 digests
/// are kept, so that comparing is over equal lengths and constant time.
#[derive(Clone, Default)]
pub struct Tokens {
    entries: Vec<([u8; 32], Principal)>,
}

impl std::fmt::Debug for Tokens {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Tokens({} entries)", self.entries.len())
    }
}

/// Whether `name` can be a principal's name: short, printable, no spaces.
fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.chars().count() <= MAX_NAME_CHARS
        && name.chars().all(|c| c.is_ascii_alphanumeric() || "._-@:+".contains(c))
}

impl Tokens {
    /// No tokens.
    pub fn new() -> Tokens {
        Tokens::default()
    }

    /// With `token` for `role` and `name` (for in-process coordinators, `tessera render`'s).
    pub fn with(mut self, role: Role, name: &str, token: &str) -> Tokens {
        self.entries
            .push((*blake3::hash(token.as_bytes()).as_bytes(), Principal { role, name: name.into() }));
        self
    }

    /// Parses a tokens file: one `ROLE NAME TOKEN` a line, `#` comments and blank lines
    /// ignored; roles `admin`, `submitter`, `worker`, `viewer`. `path` names it in errors,
    /// which never quote a token.
    pub fn parse(text: &str, path: &str) -> Result<Tokens, AuthError> {
        let mut tokens = Tokens::new();
        for (i, line) in text.lines().enumerate() {
            let err = |reason: String| AuthError::Line { path: path.to_string(), line: i + 1, reason };
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split_whitespace().collect();
            let [role, name, token] = fields[..] else {
                return Err(err(format!(
                    "expected `ROLE NAME TOKEN` (three fields), found {} fields",
                    fields.len()
                )));
            };
            let role = Role::parse(role).ok_or_else(|| {
                err(format!("unknown role {role:?}; expected admin, submitter, worker or viewer"))
            })?;
            if !valid_name(name) {
                return Err(err(format!(
                    "name {name:?} must be 1 to {MAX_NAME_CHARS} letters, digits or ._-@:+"
                )));
            }
            if token.chars().count() < MIN_TOKEN_CHARS || !token.bytes().all(|b| b.is_ascii_graphic()) {
                return Err(err(format!(
                    "the token of {name} must be at least {MIN_TOKEN_CHARS} printable ASCII characters"
                )));
            }
            let digest = *blake3::hash(token.as_bytes()).as_bytes();
            if tokens.entries.iter().any(|(d, _)| *d == digest) {
                return Err(err(format!("the token of {name} is already given to another line")));
            }
            tokens.entries.push((digest, Principal { role, name: name.to_string() }));
        }
        Ok(tokens)
    }

    /// Reads and parses a tokens file; one every user can read is refused.
    pub fn read(path: &Path) -> Result<Tokens, AuthError> {
        let shown = path.display().to_string();
        let read = |e: std::io::Error| AuthError::Read { path: shown.clone(), reason: e.to_string() };
        let meta = std::fs::metadata(path).map_err(read)?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = meta.permissions().mode() & 0o777;
            if mode & 0o004 != 0 {
                return Err(AuthError::Exposed { path: shown, mode });
            }
        }
        if meta.len() > 1 << 20 {
            return Err(AuthError::Read {
                path: shown,
                reason: format!("{} bytes is too large", meta.len()),
            });
        }
        let text = std::fs::read_to_string(path).map_err(read)?;
        Tokens::parse(&text, &shown)
    }

    /// How many tokens.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The principal of `token`. Every entry is compared, whichever matches, so the time
    /// taken says nothing about which token (or how much of one) was right.
    fn find(&self, token: &[u8]) -> Option<&Principal> {
        let digest = blake3::hash(token);
        let mut found = u64::MAX;
        for (i, (d, _)) in self.entries.iter().enumerate() {
            let hit = d.ct_eq(digest.as_bytes());
            found = u64::conditional_select(&found, &(i as u64), hit);
        }
        self.entries.get(usize::try_from(found).ok()?).map(|(_, p)| p)
    }
}

/// How a coordinator authenticates its callers and what submitters may ask.
#[derive(Debug, Clone)]
pub struct Auth {
    tokens: Option<Tokens>,
    client_certs: bool,
    max_priority: i32,
}

/// The highest priority a submitter may ask by default: above it needs an admin, so that
/// no submitter can starve the others.
pub const DEFAULT_MAX_PRIORITY: i32 = 0;

impl Default for Auth {
    fn default() -> Self {
        Auth::open()
    }
}

impl Auth {
    /// No authentication: every caller is the admin `anonymous` (in-process coordinators,
    /// tests, and a coordinator on loopback that was not given tokens).
    pub fn open() -> Auth {
        Auth { tokens: None, client_certs: false, max_priority: DEFAULT_MAX_PRIORITY }
    }

    /// Callers authenticate with one of `tokens`, or with a client certificate that the
    /// TLS layer verified (`client_certs`, mutual TLS) and that names a role in its OU.
    pub fn new(tokens: Option<Tokens>, client_certs: bool) -> Auth {
        Auth { tokens, client_certs, max_priority: DEFAULT_MAX_PRIORITY }
    }

    /// With another ceiling on submitters' priorities.
    pub fn max_priority(mut self, max: i32) -> Auth {
        self.max_priority = max;
        self
    }

    /// Whether callers must prove who they are.
    pub fn required(&self) -> bool {
        self.tokens.is_some() || self.client_certs
    }

    /// The caller of `request`, or why it is refused.
    fn authenticate<T>(&self, request: &Request<T>) -> Result<Principal, Status> {
        if !self.required() {
            return Ok(Principal { role: Role::Admin, name: "anonymous".into() });
        }
        if self.client_certs {
            if let Some(p) = certificate_principal(request)? {
                return Ok(p);
            }
        }
        if self.tokens.is_none() {
            return self.authenticate_token(None);
        }
        let Some(header) = request.metadata().get("authorization") else {
            return Err(Status::unauthenticated(
                "no token: give the client one with --token-file FILE or the TESSERA_TOKEN environment variable",
            ));
        };
        let token = header
            .as_bytes()
            .strip_prefix(b"Bearer ")
            .ok_or_else(|| Status::unauthenticated("the authorization header is not `Bearer TOKEN`"))?;
        self.authenticate_token(Some(token))
    }

    /// The principal of a bearer token, for callers that are not gRPC calls (the web API's
    /// `Authorization` header and its login): the admin `anonymous` when no authentication
    /// is required, else the token's principal (looked up in constant time), or
    /// `UNAUTHENTICATED` for no token (`None`) or an unknown one.
    pub fn authenticate_token(&self, token: Option<&[u8]>) -> Result<Principal, Status> {
        if !self.required() {
            return Ok(Principal { role: Role::Admin, name: "anonymous".into() });
        }
        let Some(tokens) = &self.tokens else {
            return Err(Status::unauthenticated(
                "this coordinator takes client certificates that name a role (OU); yours names none",
            ));
        };
        let token = token.ok_or_else(|| Status::unauthenticated("no token"))?;
        tokens.find(token).cloned().ok_or_else(|| Status::unauthenticated("unknown token"))
    }
}

/// The principal of a verified client certificate: its common name, and the role its
/// organizational unit names. `None` without a certificate or without a role in it.
fn certificate_principal<T>(request: &Request<T>) -> Result<Option<Principal>, Status> {
    let Some(certs) = request.peer_certs() else { return Ok(None) };
    let Some(leaf) = certs.first() else { return Ok(None) };
    let (_, cert) = x509_parser::parse_x509_certificate(leaf.as_ref())
        .map_err(|e| Status::unauthenticated(format!("the client certificate cannot be read: {e}")))?;
    let subject = cert.subject();
    let cn = subject.iter_common_name().next().and_then(|a| a.as_str().ok());
    let role = subject.iter_organizational_unit().filter_map(|a| a.as_str().ok()).find_map(Role::parse);
    match (cn, role) {
        (Some(name), Some(role)) if valid_name(name) => Ok(Some(Principal { role, name: name.to_string() })),
        (Some(name), Some(_)) => Err(Status::unauthenticated(format!(
            "the client certificate's common name {name:?} is not a valid name"
        ))),
        _ => Ok(None),
    }
}

/// The server's interceptor: authenticates every call before its message is decoded and
/// hands the principal to the RPC in the request's extensions.
#[derive(Debug, Clone)]
pub struct Authenticate(pub(super) Arc<Auth>);

impl tonic::service::Interceptor for Authenticate {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        match self.0.authenticate(&request) {
            Ok(p) => {
                request.extensions_mut().insert(p);
                Ok(request)
            }
            Err(s) => {
                info!(peer = ?request.remote_addr(), "call refused: {}", s.message());
                Err(s)
            }
        }
    }
}

/// The caller of `request` if it may do `action`: `UNAUTHENTICATED` without a principal
/// (the service served without its interceptor), `PERMISSION_DENIED` for another role.
pub(super) fn require<T>(request: &Request<T>, action: Action) -> Result<Principal, Status> {
    require_of(request.extensions().get::<Principal>(), action)
}

/// As `require`, for the principal the interceptor left in a request's extensions (the
/// submit gate asks before it reads a body or reserves budget).
pub(super) fn require_of(p: Option<&Principal>, action: Action) -> Result<Principal, Status> {
    let p = p.cloned().ok_or_else(|| Status::unauthenticated("the call carries no verified identity"))?;
    if action.roles().contains(&p.role) {
        return Ok(p);
    }
    let allowed: Vec<&str> = action.roles().iter().map(|r| r.name()).collect();
    info!(principal = %p.name, role = %p.role, "{} refused", action.name());
    Err(Status::permission_denied(format!(
        "{} `{}` may not {}: that needs the {} role",
        p.role,
        p.name,
        action.name(),
        allowed.join(" or ")
    )))
}

/// The caller of `request`, whose role `require` already checked.
pub(super) fn caller<T>(request: &Request<T>) -> Result<Principal, Status> {
    request
        .extensions()
        .get::<Principal>()
        .cloned()
        .ok_or_else(|| Status::unauthenticated("the call carries no verified identity"))
}

/// The verified name of the caller of `request`, once the RPC layer authenticated it: a
/// worker's identity.
pub(super) fn principal_name<T>(request: &Request<T>) -> Option<String> {
    request.extensions().get::<Principal>().map(|p| p.name.clone())
}

impl CoordinatorService {
    /// Refuses a submitter's call on a job that is not its own; others pass (their role
    /// was checked). For a submitter a job that does not exist is `NOT_FOUND` here, not
    /// later: ids are never reused, so a job that exists and is its own now stays its own
    /// when the handler acts (a job submitted by another between a check that let a
    /// missing id pass and the act could otherwise be cancelled by a guess of its id).
    pub(super) fn check_owner(&self, who: &Principal, job: JobId) -> Result<(), Status> {
        if who.role != Role::Submitter {
            return Ok(());
        }
        match self.farm().job(job) {
            Some(j) if j.owner != who.name => {
                info!(principal = %who.name, %job, "refused: another's job");
                Err(Status::permission_denied(format!("{job} belongs to another submitter")))
            }
            Some(_) => Ok(()),
            None => Err(Status::not_found(format!("no {job}"))),
        }
    }

    /// Refuses a submitter's priority above the ceiling.
    pub(super) fn check_priority(&self, who: &Principal, priority: i32) -> Result<(), Status> {
        let max = self.auth.max_priority;
        if who.role == Role::Submitter && priority > max {
            return Err(Status::permission_denied(format!(
                "priority {priority} is above {max}, the most a submitter may ask (--max-priority); an admin may submit it"
            )));
        }
        Ok(())
    }

    /// Whether `who` sees `owner`'s jobs in Status.
    pub(super) fn sees_jobs_of(who: &Principal, owner: &str) -> bool {
        who.role != Role::Submitter || who.name == owner
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = "# the farm's tokens\n\
        admin root 0123456789abcdef0123\n\
        \n\
        submitter alice aaaaaaaaaaaaaaaaaaaa\n\
        worker node-1 wwwwwwwwwwwwwwwwwwww\n\
        viewer wall   vvvvvvvvvvvvvvvvvvvv\n";

    fn request(header: Option<&str>) -> Request<()> {
        let mut r = Request::new(());
        if let Some(h) = header {
            r.metadata_mut().insert("authorization", h.parse().unwrap());
        }
        r
    }

    #[test]
    fn tokens_name_their_principals() {
        let auth = Auth::new(Some(Tokens::parse(FILE, "tokens").unwrap()), false);
        assert!(auth.required());
        let p = auth.authenticate(&request(Some("Bearer aaaaaaaaaaaaaaaaaaaa"))).unwrap();
        assert_eq!(p, Principal { role: Role::Submitter, name: "alice".into() });
        let p = auth.authenticate(&request(Some("Bearer vvvvvvvvvvvvvvvvvvvv"))).unwrap();
        assert_eq!(p, Principal { role: Role::Viewer, name: "wall".into() });
        for (header, says) in [
            (None, "no token"),
            (Some("Bearer aaaaaaaaaaaaaaaaaaab"), "unknown token"),
            (Some("Bearer "), "unknown token"),
            (Some("aaaaaaaaaaaaaaaaaaaa"), "not `Bearer TOKEN`"),
        ] {
            let e = auth.authenticate(&request(header)).unwrap_err();
            assert_eq!(e.code(), tonic::Code::Unauthenticated, "{header:?}");
            assert!(e.message().contains(says), "{header:?}: {}", e.message());
        }
    }

    #[test]
    fn an_open_coordinator_makes_everyone_admin() {
        let p = Auth::open().authenticate(&request(None)).unwrap();
        assert_eq!(p.role, Role::Admin);
    }

    #[test]
    fn roles_allow_what_the_documentation_says() {
        let allowed = |role: Role| -> Vec<Action> {
            use Action::*;
            [Submit, Status, FetchImage, Watch, Pause, Cancel, Work]
                .into_iter()
                .filter(|a| {
                    let mut r = Request::new(());
                    r.extensions_mut().insert(Principal { role, name: "x".into() });
                    require(&r, *a).is_ok()
                })
                .collect()
        };
        use Action::*;
        assert_eq!(allowed(Role::Admin), [Submit, Status, FetchImage, Watch, Pause, Cancel, Work]);
        assert_eq!(allowed(Role::Submitter), [Submit, Status, FetchImage, Watch, Pause, Cancel]);
        assert_eq!(allowed(Role::Worker), [Work]);
        assert_eq!(allowed(Role::Viewer), [Status, FetchImage, Watch]);
        let e = require(&Request::new(()), Status).unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let mut r = Request::new(());
        r.extensions_mut().insert(Principal { role: Role::Viewer, name: "wall".into() });
        let e = require(&r, Submit).unwrap_err();
        assert_eq!(e.code(), tonic::Code::PermissionDenied);
        assert_eq!(e.message(), "viewer `wall` may not submit: that needs the admin or submitter role");
    }

    #[test]
    fn bad_tokens_files_say_where_without_quoting_tokens() {
        for (text, says) in [
            ("admin root\n", "tokens:1: expected `ROLE NAME TOKEN` (three fields), found 2 fields"),
            ("boss root 0123456789abcdef0123\n", "tokens:1: unknown role \"boss\""),
            ("# c\nadmin root short\n", "tokens:2: the token of root must be at least 16"),
            ("admin r/oot 0123456789abcdef0123\n", "tokens:1: name \"r/oot\""),
            (
                "admin a 0123456789abcdef0123\nviewer b 0123456789abcdef0123\n",
                "tokens:2: the token of b is already",
            ),
        ] {
            let e = Tokens::parse(text, "tokens").unwrap_err().to_string();
            assert!(e.starts_with(says), "{text:?}: {e}");
            assert!(!e.contains("0123456789abcdef0123") && !e.contains("short"), "{e}");
        }
    }

    #[cfg(unix)]
    #[test]
    fn a_tokens_file_every_user_can_read_is_refused() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tokens");
        std::fs::write(&path, FILE).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        let e = Tokens::read(&path).unwrap_err();
        assert!(matches!(e, AuthError::Exposed { mode: 0o644, .. }), "{e:?}");
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
        assert_eq!(Tokens::read(&path).unwrap().len(), 4);
    }

    #[test]
    fn every_entry_is_compared() {
        // The lookup has no early exit: the last entry is found like the first.
        let tokens = Tokens::parse(FILE, "tokens").unwrap();
        assert_eq!(tokens.find(b"0123456789abcdef0123").map(|p| p.name.as_str()), Some("root"));
        assert_eq!(tokens.find(b"vvvvvvvvvvvvvvvvvvvv").map(|p| p.name.as_str()), Some("wall"));
        assert_eq!(tokens.find(b"nope"), None);
    }
}
