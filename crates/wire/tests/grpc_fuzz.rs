//! Property tests against the real learner and selector servers on 127.0.0.1, port 0: request
//! bodies that are random bytes, truncated or mangled valid requests, unknown enum values and
//! oversized labels. Every call gets a status (never a dropped connection or a crashed server),
//! and the server keeps its state: a valid request afterwards works and the published weights
//! are unchanged.

use std::sync::OnceLock;

use proptest::prelude::*;
use prost::bytes::{Buf, BufMut};
use prost::Message as _;
use terl_wire::{
    connect_learner, connect_selector, pb, serve_learner, serve_selector, CheckpointRequest,
    CheckpointSaved, LearnerBackend, LearnerStatus, SelectorBackend, SelectorStatus, Tensor,
    WeightHub, Weights, WeightsKind,
};
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};
use tonic::{Code, Status};

/// Sends and receives message bodies as raw bytes, so a test can send what no typed client
/// would.
#[derive(Debug, Clone, Copy, Default)]
struct RawCodec;

impl Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawCodec;
    type Decoder = RawCodec;
    fn encoder(&mut self) -> Self::Encoder {
        RawCodec
    }
    fn decoder(&mut self) -> Self::Decoder {
        RawCodec
    }
}

impl Encoder for RawCodec {
    type Item = Vec<u8>;
    type Error = Status;
    fn encode(&mut self, item: Vec<u8>, dst: &mut EncodeBuf<'_>) -> Result<(), Status> {
        dst.put_slice(&item);
        Ok(())
    }
}

impl Decoder for RawCodec {
    type Item = Vec<u8>;
    type Error = Status;
    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<Vec<u8>>, Status> {
        let mut out = vec![0; src.remaining()];
        src.copy_to_slice(&mut out);
        Ok(Some(out))
    }
}

struct TestLearner {
    hub: WeightHub,
}

impl LearnerBackend for TestLearner {
    async fn status(&self) -> Result<LearnerStatus, Status> {
        Ok(LearnerStatus {
            run_id: "fuzz".into(),
            updates: 1234,
            policy_version: self.hub.latest_version(WeightsKind::Policy),
            ..LearnerStatus::default()
        })
    }
    async fn save_checkpoint(&self, request: CheckpointRequest) -> Result<CheckpointSaved, Status> {
        Ok(CheckpointSaved {
            path: format!("ckpt/{}.safetensors", request.label.unwrap_or_default()),
            learner_update: 1234,
            policy_version: self.hub.latest_version(WeightsKind::Policy),
        })
    }
    fn weight_hub(&self) -> &WeightHub {
        &self.hub
    }
}

struct TestSelector;

impl SelectorBackend for TestSelector {
    async fn status(&self) -> Result<SelectorStatus, Status> {
        Ok(SelectorStatus {
            run_id: "fuzz".into(),
            episodes_seen: 40,
            ..SelectorStatus::default()
        })
    }
}

/// One runtime with both servers, shared by every case.
struct Servers {
    rt: tokio::runtime::Runtime,
    learner: String,
    selector: String,
    hub: WeightHub,
}

fn servers() -> &'static Servers {
    static SERVERS: OnceLock<Servers> = OnceLock::new();
    SERVERS.get_or_init(|| {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let hub = WeightHub::new();
        let tensors = vec![
            Tensor::new("l0.weight", vec![3, 2], vec![0.5; 6]).unwrap(),
            Tensor::new("l0.bias", vec![3], vec![-0.5; 3]).unwrap(),
        ];
        hub.publish(&Weights::new(WeightsKind::Policy, 7, 70, tensors).unwrap())
            .unwrap();
        let (learner, selector) = rt.block_on(async {
            let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
            let s = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
            let addrs = (
                l.local_addr().unwrap().to_string(),
                s.local_addr().unwrap().to_string(),
            );
            let backend = TestLearner { hub: hub.clone() };
            tokio::spawn(serve_learner(l, backend, std::future::pending()));
            tokio::spawn(serve_selector(s, TestSelector, std::future::pending()));
            addrs
        });
        Servers {
            rt,
            learner,
            selector,
            hub,
        }
    })
}

const PATHS: [(&str, bool); 4] = [
    ("/terl.v1.Learner/GetStatus", true),
    ("/terl.v1.Learner/SaveCheckpoint", true),
    ("/terl.v1.Learner/WatchWeights", true),
    ("/terl.v1.Selector/GetStatus", false),
];

/// Sends `body` to `path` as one request message and returns the call's status (`Ok` for an
/// accepted call; for the weight stream, the first item).
async fn call(addr: &str, path: &'static str, body: Vec<u8>) -> Result<(), Status> {
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .expect("the server accepts connections");
    let mut grpc = tonic::client::Grpc::new(channel);
    grpc.ready().await.expect("ready");
    let path = tonic::codegen::http::uri::PathAndQuery::from_static(path);
    if path.path().ends_with("WatchWeights") {
        let mut stream = grpc
            .server_streaming(tonic::Request::new(body), path, RawCodec)
            .await?
            .into_inner();
        // The first item is the published version (or nothing for kinds never published).
        let first =
            tokio::time::timeout(std::time::Duration::from_millis(200), stream.message()).await;
        if let Ok(item) = first {
            item?;
        }
        Ok(())
    } else {
        grpc.unary(tonic::Request::new(body), path, RawCodec)
            .await
            .map(|_| ())
    }
}

/// The server answered with a clear status and still works: a valid status call succeeds and
/// the published weights are the ones from before.
fn check_alive(s: &Servers, result: Result<(), Status>) -> Result<(), TestCaseError> {
    if let Err(status) = &result {
        prop_assert!(
            matches!(
                status.code(),
                Code::InvalidArgument | Code::Internal | Code::OutOfRange | Code::ResourceExhausted
            ),
            "{status:?}"
        );
        prop_assert!(!status.message().is_empty(), "{status:?}");
    }
    s.rt.block_on(async {
        let mut l = connect_learner(&s.learner).await.unwrap();
        let status = l.status().await.expect("learner still answers");
        assert_eq!((status.updates, status.policy_version), (1234, 7));
        let mut sel = connect_selector(&s.selector).await.unwrap();
        assert_eq!(
            sel.status()
                .await
                .expect("selector still answers")
                .episodes_seen,
            40
        );
    });
    prop_assert_eq!(s.hub.latest_version(WeightsKind::Policy), 7);
    Ok(())
}

/// Valid request bodies to mangle.
fn valid_bodies() -> Vec<Vec<u8>> {
    vec![
        pb::SaveCheckpointRequest {
            label: "before-eval".into(),
        }
        .encode_to_vec(),
        pb::WatchWeightsRequest {
            kinds: vec![1, 2, 3],
            actor_id: Some(4),
            host: "actor-host".into(),
        }
        .encode_to_vec(),
        pb::GetLearnerStatusRequest::default().encode_to_vec(),
    ]
}

/// A fixed seed: the same cases on every run, so a failure is reproducible and CI is stable.
fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x7e71_0005),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(config(48))]

    /// Random bytes as a request body to every RPC of both servers.
    #[test]
    fn random_request_bodies_get_a_status_and_change_nothing(
        path in 0usize..PATHS.len(),
        body in proptest::collection::vec(any::<u8>(), 0..512),
    ) {
        let s = servers();
        let (path, learner) = PATHS[path];
        let addr = if learner { &s.learner } else { &s.selector };
        let result = s.rt.block_on(call(addr, path, body));
        check_alive(s, result)?;
    }

    /// Valid requests cut short, with a flipped byte, or with a varint length that claims more
    /// than the body holds.
    #[test]
    fn mangled_valid_requests_get_a_status_and_change_nothing(
        which in 0usize..3,
        path in 0usize..3,
        cut in any::<prop::sample::Index>(),
        flip in any::<prop::sample::Index>(),
        mask in 1u8..=255,
        huge_len in any::<bool>(),
    ) {
        let s = servers();
        let mut body = valid_bodies()[which].clone();
        if huge_len {
            // Field 1, length-delimited, claiming 2^40 bytes.
            body = vec![0x0a, 0x80, 0x80, 0x80, 0x80, 0x80, 0x20, b'x'];
        } else if !body.is_empty() {
            let at = flip.index(body.len());
            body[at] ^= mask;
            body.truncate(cut.index(body.len() + 1));
        }
        let result = s.rt.block_on(call(&s.learner, PATHS[path].0, body));
        check_alive(s, result)?;
    }

    /// Unknown weight kinds and oversized or path-like checkpoint labels are refused with
    /// INVALID_ARGUMENT.
    #[test]
    fn bad_fields_are_invalid_arguments(
        kind in 4i32..i32::MAX,
        label in "[./\\\\a-z]{0,8}\\.\\./[a-z]{0,8}",
    ) {
        let s = servers();
        let watch = pb::WatchWeightsRequest { kinds: vec![1, kind], ..Default::default() }.encode_to_vec();
        let result = s.rt.block_on(call(&s.learner, PATHS[2].0, watch));
        prop_assert_eq!(result.as_ref().map_err(|e| e.code()), Err(Code::InvalidArgument));
        check_alive(s, result)?;
        let save = pb::SaveCheckpointRequest { label }.encode_to_vec();
        let result = s.rt.block_on(call(&s.learner, PATHS[1].0, save));
        prop_assert_eq!(result.as_ref().map_err(|e| e.code()), Err(Code::InvalidArgument));
        check_alive(s, result)?;
    }
}
