//! Everything that can fail while talking to iceoryx2. iceoryx2's own error is kept as the source (not
//! flattened into text), and the errors worth retrying while a service is set up are recognised by variant.

use iceoryx2::service::builder::event::{EventCreateError, EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeCreateError, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::builder::request_response::{
    RequestResponseCreateError, RequestResponseOpenError, RequestResponseOpenOrCreateError,
};

/// An iceoryx2 error of any call, boxed: its types differ per call.
pub type IceoryxError = Box<dyn std::error::Error + Send + Sync + 'static>;

#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// A node, service or prefix name iceoryx2 does not accept (its error says why).
    #[error("invalid name `{name}`: {detail}")]
    Name { name: String, detail: String },
    /// An iceoryx2 call failed while doing `context`.
    #[error("{context}")]
    Iceoryx {
        context: String,
        #[source]
        source: IceoryxError,
    },
    /// A sample that does not keep its topic's contract.
    #[error("{topic}: {detail}")]
    Contract { topic: &'static str, detail: String },
}

/// Wraps an iceoryx2 error with what was being done.
pub fn iox<E: std::error::Error + Send + Sync + 'static>(context: impl Into<String>) -> impl FnOnce(E) -> IpcError {
    let context = context.into();
    move |e| IpcError::Iceoryx { context, source: Box::new(e) }
}

/// Opening a service can fail for a moment while another process's dead-node cleanup or creation of the same
/// service is in progress (upstream #1578): worth a short retry, unlike every other failure.
pub trait Transient {
    fn is_transient(&self) -> bool;
}

impl Transient for PublishSubscribeOpenOrCreateError {
    fn is_transient(&self) -> bool {
        match self {
            Self::PublishSubscribeOpenError(e) => matches!(
                e,
                PublishSubscribeOpenError::IsMarkedForDestruction
                    | PublishSubscribeOpenError::ServiceInCorruptedState
                    | PublishSubscribeOpenError::HangsInCreation
            ),
            Self::PublishSubscribeCreateError(e) => matches!(
                e,
                PublishSubscribeCreateError::ServiceInCorruptedState
                    | PublishSubscribeCreateError::IsBeingCreatedByAnotherInstance
                    | PublishSubscribeCreateError::HangsInCreation
            ),
            Self::SystemInFlux => true,
        }
    }
}

impl Transient for EventOpenOrCreateError {
    fn is_transient(&self) -> bool {
        match self {
            Self::EventOpenError(e) => matches!(
                e,
                EventOpenError::IsMarkedForDestruction
                    | EventOpenError::ServiceInCorruptedState
                    | EventOpenError::HangsInCreation
            ),
            Self::EventCreateError(e) => matches!(
                e,
                EventCreateError::ServiceInCorruptedState | EventCreateError::IsBeingCreatedByAnotherInstance
            ),
            Self::SystemInFlux => true,
        }
    }
}

impl Transient for RequestResponseOpenOrCreateError {
    fn is_transient(&self) -> bool {
        match self {
            Self::RequestResponseOpenError(e) => matches!(
                e,
                RequestResponseOpenError::IsMarkedForDestruction
                    | RequestResponseOpenError::ServiceInCorruptedState
                    | RequestResponseOpenError::HangsInCreation
            ),
            Self::RequestResponseCreateError(e) => matches!(
                e,
                RequestResponseCreateError::ServiceInCorruptedState
                    | RequestResponseCreateError::IsBeingCreatedByAnotherInstance
                    | RequestResponseCreateError::HangsInCreation
            ),
            Self::SystemInFlux => true,
        }
    }
}
