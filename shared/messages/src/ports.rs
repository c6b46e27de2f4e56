//! Opening topics: the only way a process reaches another, so every service is created with the QoS
//! of [`crate::topics`]. An [`Outbox`] publishes and then notifies; an [`Inbox`] receives and exposes
//! its listener so a process can block on it in a WaitSet.
//!
//! A topic of one publisher (`max_publishers = 1`: the thrusters' setpoints) is *exclusive*: an
//! [`Outbox`] opened while another process publishes on it and is alive is refused with an error
//! naming that process; the place of a publisher whose process died is freed first. Every topic's
//! event service announces a publisher whose process died ([`PUBLISHER_DIED`]) once its leftovers
//! are removed, so a consumer blocked on it learns of the death at once.

use crate::payload::{CameraFrameHeader, VideoUnit};
use crate::topics::{Endpoint, Topic};
use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::NodeView;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use std::fmt::Debug;

type Ipc = ipc::Service;
type SliceFactory<H> = PortFactory<Ipc, [u8], H>;

/// The header of a slice topic's samples: the camera's frames ([`CameraFrameHeader`]), its video
/// ([`VideoUnit`]).
pub trait SliceHeader: Debug + Copy + Default + ZeroCopySend + 'static {}
impl SliceHeader for CameraFrameHeader {}
impl SliceHeader for VideoUnit {}

/// A port could not be opened or used; names the service.
#[derive(Debug, thiserror::Error)]
#[error("{what} on `{service}`: {reason}")]
pub struct PortError {
    pub service: String,
    pub what: &'static str,
    pub reason: String,
}

fn fail<'a>(service: &'a str, what: &'static str) -> impl FnOnce(&dyn Debug) -> PortError + 'a {
    move |e| PortError {
        service: service.to_owned(),
        what,
        reason: format!("{e:?}"),
    }
}

/// A fixed-size payload that can be sent between processes.
pub trait Payload: Debug + Copy + Default + ZeroCopySend + IceoryxSend + 'static {}
impl<T: Debug + Copy + Default + ZeroCopySend + IceoryxSend + 'static> Payload for T {}

fn service_name(service: &str) -> Result<ServiceName, PortError> {
    ServiceName::new(service).map_err(|e| fail(service, "invalid service name")(&e))
}

/// The event a topic's listeners receive when a publisher's process is found dead and its leftovers
/// are removed (iceoryx2's `notifier_dead_event`); publishers notify with event 0.
pub const PUBLISHER_DIED: usize = 254;

/// Opens (or creates) the event service beside a topic, with the topic's QoS.
pub fn open_event(
    node: &Node<Ipc>,
    service: &str,
    qos: &crate::Qos,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<Ipc>, PortError> {
    node.service_builder(&service_name(service)?)
        .event()
        .max_notifiers(qos.max_publishers)
        .max_listeners(qos.max_subscribers)
        .max_nodes(qos.max_nodes)
        .notifier_dead_event(EventId::new(PUBLISHER_DIED))
        .open_or_create()
        .map_err(|e| fail(service, "cannot open the event service")(&e))
}

/// Opens (or creates) the heartbeat event service of process `name` (see [`crate::topics::health`]):
/// the deadline is part of the service, so every opener agrees on it.
pub fn open_heartbeat(
    node: &Node<Ipc>,
    endpoint: Endpoint,
    name: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<Ipc>, PortError> {
    use crate::topics::health;
    let service = health::service_name(endpoint, name);
    node.service_builder(&service_name(&service)?)
        .event()
        .deadline(health::HEARTBEAT_DEADLINE)
        .max_notifiers(health::MAX_NOTIFIERS)
        .max_listeners(health::MAX_LISTENERS)
        .max_nodes(health::MAX_NODES)
        .open_or_create()
        .map_err(|e| fail(&service, "cannot open the heartbeat")(&e))
}

/// Notifies a process's heartbeat. The event id is the process's restart count (see
/// [`crate::topics::health::MAX_RESTARTS_ID`]): a listener tells a restarted process from its
/// predecessor, on this host or across the shore link.
pub struct Heartbeat {
    service: String,
    notifier: Notifier<Ipc>,
    id: EventId,
}

impl Heartbeat {
    pub fn open(
        node: &Node<Ipc>,
        endpoint: Endpoint,
        name: &str,
        restarts: usize,
    ) -> Result<Self, PortError> {
        let service = crate::topics::health::service_name(endpoint, name);
        let notifier = open_heartbeat(node, endpoint, name)?
            .notifier_builder()
            .create()
            .map_err(|e| fail(&service, "cannot create a notifier")(&e))?;
        let id = EventId::new(restarts.min(crate::topics::health::MAX_RESTARTS_ID));
        Ok(Heartbeat {
            service,
            notifier,
            id,
        })
    }

    /// One beat. A beat later than the deadline is still a beat (the notification goes out; the
    /// listeners have seen the miss already), so that is not an error.
    pub fn beat(&self) -> Result<(), PortError> {
        use iceoryx2::port::notifier::NotifierNotifyError;
        match self.notifier.notify_with_custom_event_id(self.id) {
            Ok(_) | Err(NotifierNotifyError::MissedDeadline) => Ok(()),
            Err(e) => Err(fail(&self.service, "cannot notify")(&e)),
        }
    }
}

/// A listener of the topic `service`'s event: notified after each message published on it.
pub fn open_listener(
    node: &Node<Ipc>,
    service: &str,
    qos: &crate::Qos,
) -> Result<Listener<Ipc>, PortError> {
    open_event(node, service, qos)?
        .listener_builder()
        .create()
        .map_err(|e| fail(service, "cannot create a listener")(&e))
}

/// The processes publishing on a topic, by the state of their iceoryx2 node.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Publishers {
    /// The names of the live publishers' nodes (the process names).
    pub alive: Vec<String>,
    /// Publishers whose process died and whose leftovers are still registered.
    pub dead: usize,
}

/// The states of the nodes of `publishers`; with `remove_dead`, the leftovers of the dead ones are
/// removed (which frees their places and announces [`PUBLISHER_DIED`]).
fn publisher_states(node: &Node<Ipc>, ids: &[UniqueNodeId], remove_dead: bool) -> Publishers {
    let mut out = Publishers::default();
    let _ = Node::<Ipc>::list(node.config(), |state| {
        match state {
            NodeState::Alive(view) if ids.contains(view.id()) => {
                let name = view
                    .details()
                    .as_ref()
                    .map(|d| d.name().to_string())
                    .unwrap_or_else(|| "?".into());
                out.alive.push(name);
            }
            NodeState::Dead(view) if ids.contains(view.id()) => {
                out.dead += 1;
                if remove_dead {
                    let _ = view.try_remove_stale_resources();
                }
            }
            _ => {}
        }
        CallbackProgression::Continue
    });
    out
}

/// The node ids of a topic's publishers.
fn publisher_ids<P: Debug + ?Sized + IceoryxSend, H: Debug + ZeroCopySend>(
    factory: &PortFactory<Ipc, P, H>,
) -> Vec<UniqueNodeId> {
    let mut ids = Vec::new();
    factory.dynamic_config().list_publishers(|p| {
        ids.push(p.node_id);
        CallbackProgression::Continue
    });
    ids
}

/// Refuses a second live publisher on an exclusive topic (see the module docs), after freeing the
/// place of a dead one.
fn check_exclusive<P: Debug + ?Sized + IceoryxSend, H: Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    service: &str,
    q: &crate::Qos,
    factory: &PortFactory<Ipc, P, H>,
) -> Result<(), PortError> {
    if q.max_publishers != 1 {
        return Ok(());
    }
    let ids = publisher_ids(factory);
    if ids.is_empty() {
        return Ok(());
    }
    let found = publisher_states(node, &ids, true);
    match found.alive.first() {
        Some(who) => Err(exclusive(service, who)),
        None => Ok(()),
    }
}

fn exclusive(service: &str, who: &str) -> PortError {
    PortError {
        service: service.to_owned(),
        what: "refused: one publisher at a time",
        reason: format!(
            "the live process `{who}` already publishes on it; this topic takes exactly one \
             publisher (stop the other one first; the place of one that died is freed by itself)"
        ),
    }
}

/// Publishes one topic's messages and wakes its subscribers.
pub struct Outbox<P: Payload> {
    service: String,
    factory: PortFactory<Ipc, P, ()>,
    publisher: Publisher<Ipc, P, ()>,
    notifier: Notifier<Ipc>,
}

/// Opens (or creates) the publish-subscribe service `service` with the topic's QoS `q`: for a port
/// that is neither an [`Outbox`] nor an [`Inbox`] (e.g. a subscriber nobody wakes), so that its QoS
/// still comes from here.
pub fn open_topic<P: Payload>(
    node: &Node<Ipc>,
    service: &str,
    q: &crate::Qos,
) -> Result<PortFactory<Ipc, P, ()>, PortError> {
    node.service_builder(&service_name(service)?)
        .publish_subscribe::<P>()
        .history_size(q.history)
        .subscriber_max_buffer_size(q.buffer.max(q.recorder_buffer))
        .enable_safe_overflow(true)
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .max_nodes(q.max_nodes)
        .open_or_create()
        .map_err(|e| fail(service, "cannot open the topic")(&e))
}

impl<P: Payload> Outbox<P> {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint, topic: &Topic<P>) -> Result<Self, PortError> {
        Self::open_service(node, &topic.service_name(endpoint), topic)
    }

    /// Opens a topic by its full service name (the hardware topics of [`crate::topics::hardware`],
    /// which live outside the endpoints' namespaces).
    pub fn open_service(
        node: &Node<Ipc>,
        service: &str,
        topic: &Topic<P>,
    ) -> Result<Self, PortError> {
        let q = &topic.qos;
        let factory = open_topic::<P>(node, service, q)?;
        check_exclusive(node, service, q, &factory)?;
        let publisher = factory.publisher_builder().create().map_err(|e| {
            match e {
                // Two newcomers at once: the other one won.
                iceoryx2::port::publisher::PublisherCreateError::ExceedsMaxSupportedPublishers
                    if q.max_publishers == 1 =>
                {
                    exclusive(service, "another publisher")
                }
                e => fail(service, "cannot create a publisher")(&e),
            }
        })?;
        let notifier = open_event(node, service, q)?
            .notifier_builder()
            .create()
            .map_err(|e| fail(service, "cannot create a notifier")(&e))?;
        Ok(Outbox {
            service: service.to_owned(),
            factory,
            publisher,
            notifier,
        })
    }

    /// Sends `msg` and wakes the subscribers; returns how many subscribers received it.
    pub fn send(&self, msg: P) -> Result<usize, PortError> {
        let n = self
            .publisher
            .send_copy(msg)
            .map_err(|e| fail(&self.service, "cannot send")(&e))?;
        self.notifier
            .notify()
            .map_err(|e| fail(&self.service, "cannot notify")(&e))?;
        Ok(n)
    }

    /// Subscribers connected now (a producer may wait for its consumers before starting).
    pub fn subscribers(&self) -> usize {
        self.factory.dynamic_config().number_of_subscribers()
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// Receives one topic's messages.
pub struct Inbox<P: Payload> {
    service: String,
    factory: PortFactory<Ipc, P, ()>,
    subscriber: Subscriber<Ipc, P, ()>,
    listener: Listener<Ipc>,
}

impl<P: Payload> Inbox<P> {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint, topic: &Topic<P>) -> Result<Self, PortError> {
        Self::open_service(node, &topic.service_name(endpoint), topic)
    }

    /// Opens a topic by its full service name (see [`Outbox::open_service`]).
    pub fn open_service(
        node: &Node<Ipc>,
        service: &str,
        topic: &Topic<P>,
    ) -> Result<Self, PortError> {
        let q = &topic.qos;
        let factory = open_topic::<P>(node, service, q)?;
        let subscriber = factory
            .subscriber_builder()
            .buffer_size(q.buffer)
            .create()
            .map_err(|e| fail(service, "cannot create a subscriber")(&e))?;
        let listener = open_listener(node, service, q)?;
        Ok(Inbox {
            service: service.to_owned(),
            factory,
            subscriber,
            listener,
        })
    }

    /// The next unread message, if any.
    pub fn receive(&self) -> Result<Option<P>, PortError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(*sample.payload())),
            Ok(None) => Ok(None),
            Err(e) => Err(fail(&self.service, "cannot receive")(&e)),
        }
    }

    /// Every unread message, oldest first.
    pub fn drain(&self) -> Result<Vec<P>, PortError> {
        let mut out = Vec::new();
        while let Some(m) = self.receive()? {
            out.push(m);
        }
        Ok(out)
    }

    /// The listener to block on (see `runtime`'s wait loop).
    pub fn listener(&self) -> &Listener<Ipc> {
        &self.listener
    }

    /// Publishers connected now.
    pub fn publishers(&self) -> usize {
        self.factory.dynamic_config().number_of_publishers()
    }

    /// The publishers' processes, alive or dead; the leftovers of dead ones are removed (their
    /// listeners, this inbox's included, then receive [`PUBLISHER_DIED`]).
    pub fn publisher_processes(&self, node: &Node<Ipc>) -> Publishers {
        publisher_states(node, &publisher_ids(&self.factory), true)
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// What a listener's pending notifications said: data arrived, and/or a publisher died.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Notified {
    pub data: bool,
    pub publisher_died: bool,
}

/// Consumes a listener's pending notifications (a WaitSet wakes again at once while any is left).
pub fn take_notifications(listener: &Listener<Ipc>) -> Notified {
    let mut n = Notified::default();
    let _ = listener.try_wait(|a| {
        if a.id.as_value() == PUBLISHER_DIED {
            n.publisher_died = true;
        } else {
            n.data = true;
        }
    });
    n
}

fn open_slice_service<H: SliceHeader>(
    node: &Node<Ipc>,
    service: &str,
    topic: &Topic<[u8]>,
) -> Result<SliceFactory<H>, PortError> {
    let q = &topic.qos;
    node.service_builder(&service_name(service)?)
        .publish_subscribe::<[u8]>()
        .user_header::<H>()
        .history_size(q.history)
        .subscriber_max_buffer_size(q.buffer.max(q.recorder_buffer))
        .enable_safe_overflow(true)
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .max_nodes(q.max_nodes)
        .open_or_create()
        .map_err(|e| fail(service, "cannot open the topic")(&e))
}

/// Publishes a slice topic's samples (a header and bytes) straight into shared memory.
pub struct SliceOutbox<H: SliceHeader> {
    service: String,
    factory: SliceFactory<H>,
    publisher: Publisher<Ipc, [u8], H>,
    notifier: Notifier<Ipc>,
    max_len: usize,
}

/// Publishes camera frames: the image is written straight into shared memory.
pub type FrameOutbox = SliceOutbox<CameraFrameHeader>;
/// Publishes the camera's video, an access unit a sample.
pub type VideoOutbox = SliceOutbox<VideoUnit>;

impl FrameOutbox {
    /// A publisher of frames of at most `max_len` bytes.
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint, max_len: usize) -> Result<Self, PortError> {
        let topic = crate::topics::CAMERA_FRAME;
        Self::open_service(node, &topic.service_name(endpoint), &topic, max_len)
    }
}

impl VideoOutbox {
    /// A publisher of access units of at most [`crate::topics::MAX_ACCESS_UNIT`] bytes; its shared
    /// memory starts at 64 KiB a sample and grows (doubling) with the largest unit sent.
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint) -> Result<Self, PortError> {
        let topic = crate::topics::CAMERA_VIDEO;
        let service = topic.service_name(endpoint);
        let factory = open_slice_service(node, &service, &topic)?;
        check_exclusive(node, &service, &topic.qos, &factory)?;
        let publisher = factory
            .publisher_builder()
            .initial_max_slice_len(64 << 10)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| fail(&service, "cannot create a publisher")(&e))?;
        Self::with_publisher(
            node,
            service,
            &topic,
            factory,
            publisher,
            crate::topics::MAX_ACCESS_UNIT,
        )
    }
}

impl<H: SliceHeader> SliceOutbox<H> {
    /// Subscribers connected now.
    pub fn subscribers(&self) -> usize {
        self.factory.dynamic_config().number_of_subscribers()
    }

    /// A publisher of frames of at most `max_len` bytes on a frame topic named in full (the hardware
    /// topics of [`crate::topics::hardware`]).
    pub fn open_service(
        node: &Node<Ipc>,
        service: &str,
        topic: &Topic<[u8]>,
        max_len: usize,
    ) -> Result<Self, PortError> {
        let factory = open_slice_service(node, service, topic)?;
        check_exclusive(node, service, &topic.qos, &factory)?;
        let publisher = factory
            .publisher_builder()
            .initial_max_slice_len(max_len.max(1))
            .create()
            .map_err(|e| fail(service, "cannot create a publisher")(&e))?;
        Self::with_publisher(node, service.to_owned(), topic, factory, publisher, max_len)
    }

    fn with_publisher(
        node: &Node<Ipc>,
        service: String,
        topic: &Topic<[u8]>,
        factory: SliceFactory<H>,
        publisher: Publisher<Ipc, [u8], H>,
        max_len: usize,
    ) -> Result<Self, PortError> {
        let notifier = open_event(node, &service, &topic.qos)?
            .notifier_builder()
            .create()
            .map_err(|e| fail(&service, "cannot create a notifier")(&e))?;
        Ok(SliceOutbox {
            service,
            factory,
            publisher,
            notifier,
            max_len,
        })
    }

    /// The largest slice this publisher sends (bytes).
    pub fn max_len(&self) -> usize {
        self.max_len
    }

    /// Loans `len` bytes of shared memory, lets `fill` write the image into them, and sends it with
    /// `header`. `fill` sees zeroed bytes.
    pub fn send_with<E>(
        &self,
        header: H,
        len: usize,
        fill: impl FnOnce(&mut [u8]) -> Result<(), E>,
    ) -> Result<Result<(), E>, PortError> {
        if len > self.max_len {
            return Err(PortError {
                service: self.service.clone(),
                what: "sample too large",
                reason: format!("{len} bytes, the publisher holds at most {}", self.max_len),
            });
        }
        let mut sample = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| fail(&self.service, "cannot loan a frame")(&e))?;
        *sample.user_header_mut() = header;
        let mut sample = sample.write_from_fn(|_| 0u8);
        if let Err(e) = fill(sample.payload_mut()) {
            return Ok(Err(e));
        }
        sample
            .send()
            .map_err(|e| fail(&self.service, "cannot send")(&e))?;
        self.notifier
            .notify()
            .map_err(|e| fail(&self.service, "cannot notify")(&e))?;
        Ok(Ok(()))
    }
}

/// Receives a slice topic's samples without copying them.
pub struct SliceInbox<H: SliceHeader> {
    service: String,
    factory: SliceFactory<H>,
    subscriber: Subscriber<Ipc, [u8], H>,
    listener: Listener<Ipc>,
}

/// Receives camera frames without copying them.
pub type FrameInbox = SliceInbox<CameraFrameHeader>;
/// Receives the camera's video.
pub type VideoInbox = SliceInbox<VideoUnit>;

impl FrameInbox {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint) -> Result<Self, PortError> {
        let topic = crate::topics::CAMERA_FRAME;
        Self::open_service(node, &topic.service_name(endpoint), &topic)
    }
}

impl VideoInbox {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint) -> Result<Self, PortError> {
        let topic = crate::topics::CAMERA_VIDEO;
        Self::open_service(node, &topic.service_name(endpoint), &topic)
    }
}

impl<H: SliceHeader> SliceInbox<H> {
    /// A subscriber of a frame topic named in full (see [`FrameOutbox::open_service`]).
    pub fn open_service(
        node: &Node<Ipc>,
        service: &str,
        topic: &Topic<[u8]>,
    ) -> Result<Self, PortError> {
        let factory = open_slice_service(node, service, topic)?;
        let subscriber = factory
            .subscriber_builder()
            .buffer_size(topic.qos.buffer)
            .create()
            .map_err(|e| fail(service, "cannot create a subscriber")(&e))?;
        let listener = open_listener(node, service, &topic.qos)?;
        Ok(SliceInbox {
            service: service.to_owned(),
            factory,
            subscriber,
            listener,
        })
    }

    /// Calls `f` with the next unread frame (header and image, in shared memory), if any.
    pub fn receive_with<R>(&self, f: impl FnOnce(&H, &[u8]) -> R) -> Result<Option<R>, PortError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(f(sample.user_header(), sample.payload()))),
            Ok(None) => Ok(None),
            Err(e) => Err(fail(&self.service, "cannot receive")(&e)),
        }
    }

    pub fn listener(&self) -> &Listener<Ipc> {
        &self.listener
    }

    /// Publishers connected now.
    pub fn publishers(&self) -> usize {
        self.factory.dynamic_config().number_of_publishers()
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// A recording subscriber of one topic: the topic's [`crate::Qos::recorder_buffer`], and no
/// listener, so a publish wakes nobody more than without it (the recorder drains its taps on a timer
/// of its own). When it falls
/// behind by more than its buffer, the publisher overwrites its oldest samples: it never blocks.
pub struct Tap<P: Payload> {
    service: String,
    subscriber: Subscriber<Ipc, P, ()>,
}

impl<P: Payload> Tap<P> {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint, topic: &Topic<P>) -> Result<Self, PortError> {
        let service = topic.service_name(endpoint);
        let subscriber = open_topic::<P>(node, &service, &topic.qos)?
            .subscriber_builder()
            .buffer_size(topic.qos.recorder_buffer)
            .create()
            .map_err(|e| fail(&service, "cannot create a subscriber")(&e))?;
        Ok(Tap {
            service,
            subscriber,
        })
    }

    /// The next unread message, if any.
    pub fn receive(&self) -> Result<Option<P>, PortError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(*sample.payload())),
            Ok(None) => Ok(None),
            Err(e) => Err(fail(&self.service, "cannot receive")(&e)),
        }
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// A recording subscriber of a slice topic (see [`Tap`]).
pub struct SliceTap<H: SliceHeader> {
    service: String,
    subscriber: Subscriber<Ipc, [u8], H>,
}

/// A recording subscriber of the camera's frames.
pub type FrameTap = SliceTap<CameraFrameHeader>;
/// A recording subscriber of the camera's video.
pub type VideoTap = SliceTap<VideoUnit>;

impl FrameTap {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint) -> Result<Self, PortError> {
        Self::open_topic(node, endpoint, &crate::topics::CAMERA_FRAME)
    }
}

impl VideoTap {
    pub fn open(node: &Node<Ipc>, endpoint: Endpoint) -> Result<Self, PortError> {
        Self::open_topic(node, endpoint, &crate::topics::CAMERA_VIDEO)
    }
}

impl<H: SliceHeader> SliceTap<H> {
    fn open_topic(
        node: &Node<Ipc>,
        endpoint: Endpoint,
        topic: &Topic<[u8]>,
    ) -> Result<Self, PortError> {
        let service = topic.service_name(endpoint);
        let subscriber = open_slice_service(node, &service, topic)?
            .subscriber_builder()
            .buffer_size(topic.qos.recorder_buffer)
            .create()
            .map_err(|e| fail(&service, "cannot create a subscriber")(&e))?;
        Ok(SliceTap {
            service,
            subscriber,
        })
    }

    /// Calls `f` with the next unread frame (header and image, in shared memory), if any.
    pub fn receive_with<R>(&self, f: impl FnOnce(&H, &[u8]) -> R) -> Result<Option<R>, PortError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(f(sample.user_header(), sample.payload()))),
            Ok(None) => Ok(None),
            Err(e) => Err(fail(&self.service, "cannot receive")(&e)),
        }
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}
