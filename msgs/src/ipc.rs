//! The one place where arthrosim's shared-memory services are opened, so that every process
//! builds them with the same settings (iceoryx2 refuses a subscriber that asks for more than
//! the existing service offers).
//!
//! Service names are `arthrosim/<session>/<Topic::SERVICE>`; the session prefix keeps
//! concurrent sessions (and parallel tests) apart.

use crate::Topic;
use iceoryx2::node::NodeState;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

pub use iceoryx2::prelude::ipc;

/// The iceoryx2 service flavour used between processes.
pub type IpcNode = Node<ipc::Service>;
pub type IpcPublisher<T> = Publisher<ipc::Service, T, ()>;
pub type IpcSubscriber<T> = Subscriber<ipc::Service, T, ()>;
pub type IpcService<T> = PortFactory<ipc::Service, T, ()>;

/// Environment variable that sets the session prefix when no flag does.
pub const SESSION_ENV: &str = "ARTHROSIM_SESSION";
/// Session prefix when neither flag nor environment names one.
pub const DEFAULT_SESSION: &str = "default";

/// Failure to set up or use a shared-memory link.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("session name {0:?} is not usable as an iceoryx2 service name (use [A-Za-z0-9_-])")]
    BadSessionName(String),
    #[error("cannot create iceoryx2 node {name:?}: {detail}")]
    Node { name: String, detail: String },
    #[error("cannot open service {service:?}: {detail}")]
    Service { service: String, detail: String },
    #[error("cannot create {port} port on {service:?}: {detail}")]
    Port {
        port: &'static str,
        service: String,
        detail: String,
    },
    #[error("cannot loan a sample on {service:?}: {detail}")]
    Loan { service: String, detail: String },
    #[error("cannot send on {service:?}: {detail}")]
    Send { service: String, detail: String },
    #[error("cannot receive on {service:?}: {detail}")]
    Receive { service: String, detail: String },
}

/// The session prefix: the given name, else `$ARTHROSIM_SESSION`, else `default`.
pub fn session_name(explicit: Option<&str>) -> Result<String, LinkError> {
    let name = match explicit {
        Some(s) => s.to_string(),
        None => std::env::var(SESSION_ENV).unwrap_or_else(|_| DEFAULT_SESSION.to_string()),
    };
    if name.is_empty()
        || name.len() > 64
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        return Err(LinkError::BadSessionName(name));
    }
    Ok(name)
}

/// Full service name of topic `T` in `session`.
pub fn service_name<T: Topic>(session: &str) -> String {
    format!("arthrosim/{session}/{}", T::SERVICE)
}

/// Creates this process's iceoryx2 node and removes the stale resources of nodes that died
/// without cleaning up (a `kill -9`'d physics or haptic process), so a restart needs no
/// manual step. Signal handling is left to the caller (`Disabled`), since each node binary
/// installs its own Ctrl-C / SIGTERM handling to stop cleanly with zero force.
pub fn create_node(name: &str) -> Result<IpcNode, LinkError> {
    set_log_level_from_env_or(LogLevel::Warn);
    let node_name = NodeName::new(name).map_err(|e| LinkError::Node {
        name: name.to_string(),
        detail: format!("{e:?}"),
    })?;
    let node = NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| LinkError::Node {
            name: name.to_string(),
            detail: format!("{e:?}"),
        })?;
    remove_dead_nodes();
    Ok(node)
}

/// Removes the shared-memory resources of dead nodes; returns how many were cleaned.
pub fn remove_dead_nodes() -> usize {
    let mut dead = Vec::new();
    let _ = Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    });
    dead.into_iter()
        .filter(|view| view.clone().try_remove_stale_resources().is_ok())
        .count()
}

/// Opens (or creates) the service for topic `T` with the settings `T` declares.
pub fn open_service<T: Topic>(node: &IpcNode, session: &str) -> Result<IpcService<T>, LinkError> {
    let service = service_name::<T>(session);
    let name = ServiceName::new(&service).map_err(|e| LinkError::Service {
        service: service.clone(),
        detail: format!("{e:?}"),
    })?;
    node.service_builder(&name)
        .publish_subscribe::<T>()
        .enable_safe_overflow(true)
        .history_size(T::HISTORY)
        .subscriber_max_buffer_size(T::MAX_BUFFER)
        .subscriber_max_borrowed_samples(4)
        .max_publishers(4)
        .max_subscribers(T::MAX_SUBSCRIBERS)
        .max_nodes(24)
        .open_or_create()
        .map_err(|e| LinkError::Service {
            service,
            detail: format!("{e:?}"),
        })
}

/// A publisher for topic `T`.
pub fn publisher<T: Topic>(node: &IpcNode, session: &str) -> Result<IpcPublisher<T>, LinkError> {
    let service = open_service::<T>(node, session)?;
    service
        .publisher_builder()
        .create()
        .map_err(|e| LinkError::Port {
            port: "publisher",
            service: service_name::<T>(session),
            detail: format!("{e:?}"),
        })
}

/// How much of the service's queue a subscriber wants.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Queue {
    /// A reader that only ever uses the newest sample (haptic loop, physics reading the
    /// device): a short queue, drained each time.
    Newest,
    /// A reader that must see every sample (the recorder): the service's whole queue.
    Every,
}

/// A subscriber for topic `T`.
pub fn subscriber<T: Topic>(
    node: &IpcNode,
    session: &str,
    queue: Queue,
) -> Result<IpcSubscriber<T>, LinkError> {
    let service = open_service::<T>(node, session)?;
    let size = match queue {
        Queue::Newest => T::MAX_BUFFER.min(4),
        Queue::Every => T::MAX_BUFFER,
    };
    service
        .subscriber_builder()
        .buffer_size(size)
        .create()
        .map_err(|e| LinkError::Port {
            port: "subscriber",
            service: service_name::<T>(session),
            detail: format!("{e:?}"),
        })
}

/// Publishes `value` by copying it straight into shared memory (no large stack temporary,
/// no heap allocation).
pub fn send_copy<T: Topic + Copy>(publisher: &IpcPublisher<T>, value: &T) -> Result<(), LinkError> {
    let mut sample = publisher.loan_uninit().map_err(|e| LinkError::Loan {
        service: T::SERVICE.to_string(),
        detail: format!("{e:?}"),
    })?;
    // SAFETY: `value` is a valid T and the loaned slot has room for exactly one T.
    let sample = unsafe {
        core::ptr::copy_nonoverlapping(value as *const T, sample.payload_mut().as_mut_ptr(), 1);
        sample.assume_init()
    };
    sample.send().map_err(|e| LinkError::Send {
        service: T::SERVICE.to_string(),
        detail: format!("{e:?}"),
    })?;
    Ok(())
}

/// Publishes a value written in place by `fill` into a zeroed slot in shared memory.
pub fn send_with<T: Topic>(
    publisher: &IpcPublisher<T>,
    fill: impl FnOnce(&mut T),
) -> Result<(), LinkError> {
    let mut sample = publisher.loan_uninit().map_err(|e| LinkError::Loan {
        service: T::SERVICE.to_string(),
        detail: format!("{e:?}"),
    })?;
    fill(T::zeroed_in(sample.payload_mut()));
    // SAFETY: zeroed_in initialised the payload.
    let sample = unsafe { sample.assume_init() };
    sample.send().map_err(|e| LinkError::Send {
        service: T::SERVICE.to_string(),
        detail: format!("{e:?}"),
    })?;
    Ok(())
}

/// Drains the subscriber's queue and copies the newest sample into `out`. Returns how many
/// samples were received (0: nothing new, `out` untouched). Never blocks, never allocates.
pub fn take_newest<T: Topic + Copy>(
    subscriber: &IpcSubscriber<T>,
    out: &mut T,
) -> Result<usize, LinkError> {
    let mut count = 0;
    loop {
        match subscriber.receive() {
            Ok(Some(sample)) => {
                *out = *sample.payload();
                count += 1;
            }
            Ok(None) => return Ok(count),
            Err(e) => {
                return Err(LinkError::Receive {
                    service: T::SERVICE.to_string(),
                    detail: format!("{e:?}"),
                })
            }
        }
    }
}

/// Calls `each` for every queued sample, oldest first (the recorder's path). Returns the count.
pub fn drain_each<T: Topic>(
    subscriber: &IpcSubscriber<T>,
    mut each: impl FnMut(&T),
) -> Result<usize, LinkError> {
    let mut count = 0;
    loop {
        match subscriber.receive() {
            Ok(Some(sample)) => {
                each(sample.payload());
                count += 1;
            }
            Ok(None) => return Ok(count),
            Err(e) => {
                return Err(LinkError::Receive {
                    service: T::SERVICE.to_string(),
                    detail: format!("{e:?}"),
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics_to_haptic::ContactFrame;

    #[test]
    fn contact_frame_round_trips_through_shared_memory() {
        let session = format!("msgs-test-{}", std::process::id());
        let node = create_node("msgs-test").unwrap();
        let publisher = publisher::<ContactFrame>(&node, &session).unwrap();
        let subscriber = subscriber::<ContactFrame>(&node, &session, Queue::Newest).unwrap();
        for seq in 1..=3u64 {
            send_with(&publisher, |f| {
                f.sequence = seq;
                f.dt_s = 0.01;
                f.contact_count = 1;
                f.row_count = 3;
                f.compliance[1] = 2.5e-4;
            })
            .unwrap();
        }
        let mut slot = Box::new(core::mem::MaybeUninit::<ContactFrame>::uninit());
        let newest = ContactFrame::zeroed_in(&mut slot);
        let n = take_newest(&subscriber, newest).unwrap();
        assert_eq!(n, 3);
        assert_eq!(newest.sequence, 3);
        assert_eq!(newest.w(0, 1), 2.5e-4);
        assert_eq!(take_newest(&subscriber, newest).unwrap(), 0);
    }

    #[test]
    fn bad_session_names_are_rejected() {
        assert!(session_name(Some("a/b")).is_err());
        assert!(session_name(Some("")).is_err());
        assert_eq!(session_name(Some("lab-1")).unwrap(), "lab-1");
    }
}
