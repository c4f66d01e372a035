//! `GET /api/events`: server-sent events, `event: status` with the `/api/jobs` JSON
//! whenever it changed, at most four a second (the jobs page uses it instead of polling).

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::response::sse::{Event, KeepAlive, Sse};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::Stream;

use crate::caller::{status as status_of, Caller};
use crate::errors::ApiError;
use crate::json::listing as listing_of;
use crate::AppState;

/// The shortest time between two events.
const MIN_INTERVAL: Duration = Duration::from_millis(250);
/// The status is sent again after this even without a change notification (rates and
/// elapsed times move on their own).
const REFRESH: Duration = Duration::from_secs(2);

/// `GET /api/events`.
pub(crate) async fn events(
    State(state): State<AppState>,
    caller: Caller,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    // The first listing here, so that a caller who may not read gets its 401/403 now.
    let first = listing_of(status_of(&state, &caller, 0).await?);
    let (tx, rx) = mpsc::channel(1);
    let mut changed = state.service.subscribe();
    tokio::spawn(async move {
        let mut last = None;
        let mut listing: Result<_, ApiError> = Ok(first);
        loop {
            match listing {
                Ok(l) => {
                    let text = serde_json::to_string(&l).expect("plain data serializes");
                    if last.as_ref() != Some(&text) {
                        if tx.send(Event::default().event("status").data(&text)).await.is_err() {
                            return;
                        }
                        last = Some(text);
                    }
                }
                // The caller's token may stop working only by a restart; say why and end.
                Err(e) => {
                    let _ = tx.send(Event::default().event("error").data(e.message)).await;
                    return;
                }
            }
            tokio::select! {
                () = tokio::time::sleep(MIN_INTERVAL) => {}
                () = tx.closed() => return,
            }
            tokio::select! {
                r = changed.changed() => if r.is_err() { return },
                () = tokio::time::sleep(REFRESH) => {}
                () = tx.closed() => return,
            }
            listing = status_of(&state, &caller, 0).await.map(listing_of);
        }
    });
    Ok(Sse::new(tokio_stream::StreamExt::map(ReceiverStream::new(rx), Ok)).keep_alive(KeepAlive::default()))
}
