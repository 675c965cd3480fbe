//! The control plane's access control over real gRPC servers on 127.0.0.1, port 0: the token on
//! every RPC (status, checkpoint, the weight stream, health, reflection), the status-readable
//! flag, the refusal of a non-loopback bind without a token, TLS with a certificate made here,
//! and that the token shows up in no log line and no `Debug` output.

use std::future::Future;
use std::io::Write;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::StreamExt;
use terl_wire::pb;
use terl_wire::{
    bind_secured, connect_learner_with, connect_selector_with, serve_learner_with,
    serve_selector_with, CheckpointRequest, CheckpointSaved, ClientOptions, ClientSecurity,
    ClientTls, ConnectError, LearnerBackend, LearnerStatus, SelectorBackend, SelectorStatus,
    ServeError, ServeOptions, ServerSecurity, ServerTls, Tensor, Token, WeightHub, Weights,
    WeightsKind,
};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::{Code, Status};

const WAIT: Duration = Duration::from_secs(10);
const TOKEN: &str = "right-token-7f3a9c2e5b1d8f40";
const WRONG: &str = "wrong-token-0a1b2c3d4e5f6789";

fn token(value: &str) -> Token {
    Token::new(value, "test").unwrap()
}

struct TestLearner {
    hub: WeightHub,
}

impl LearnerBackend for TestLearner {
    async fn status(&self) -> Result<LearnerStatus, Status> {
        Ok(LearnerStatus {
            run_id: "secured-run".into(),
            ..LearnerStatus::default()
        })
    }
    async fn save_checkpoint(&self, _: CheckpointRequest) -> Result<CheckpointSaved, Status> {
        Ok(CheckpointSaved {
            path: "runs/secured-run/checkpoints/now.safetensors".into(),
            learner_update: 7,
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
            run_id: "secured-run".into(),
            ..SelectorStatus::default()
        })
    }
}

fn weights(version: u64) -> Weights {
    let tensors = vec![Tensor::new("l0.weight", vec![2, 2], vec![version as f32; 4]).unwrap()];
    Weights::new(WeightsKind::Policy, version, version * 10, tensors).unwrap()
}

/// A learner and a selector server sharing one security setting.
struct Cluster {
    learner: SocketAddr,
    selector: SocketAddr,
    stop: Vec<oneshot::Sender<()>>,
    tasks: Vec<JoinHandle<Result<(), ServeError>>>,
}

impl Cluster {
    async fn start(security: ServerSecurity, hub: WeightHub) -> Self {
        Self::start_on("127.0.0.1:0", security, hub).await
    }

    async fn start_on(bind: &str, security: ServerSecurity, hub: WeightHub) -> Self {
        let options = ServeOptions {
            security,
            ..ServeOptions::default()
        };
        let (l_listener, s_listener) = (
            bind_secured(bind.parse().unwrap(), &options.security)
                .await
                .unwrap(),
            bind_secured(bind.parse().unwrap(), &options.security)
                .await
                .unwrap(),
        );
        let port = |l: &TcpListener| l.local_addr().unwrap().port();
        let learner = SocketAddr::from(([127, 0, 0, 1], port(&l_listener)));
        let selector = SocketAddr::from(([127, 0, 0, 1], port(&s_listener)));
        let (l_stop, l_stopped) = oneshot::channel::<()>();
        let (s_stop, s_stopped) = oneshot::channel::<()>();
        let tasks = vec![
            tokio::spawn(serve_learner_with(
                l_listener,
                TestLearner { hub },
                async {
                    let _ = l_stopped.await;
                },
                options.clone(),
            )),
            tokio::spawn(serve_selector_with(
                s_listener,
                TestSelector,
                async {
                    let _ = s_stopped.await;
                },
                options,
            )),
        ];
        Self {
            learner,
            selector,
            stop: vec![l_stop, s_stop],
            tasks,
        }
    }

    async fn stop(self) {
        for s in self.stop {
            let _ = s.send(());
        }
        for t in self.tasks {
            tokio::time::timeout(WAIT, t)
                .await
                .expect("server stops within 10 s")
                .expect("server task")
                .expect("server result");
        }
    }
}

fn client(token_value: Option<&str>) -> ClientOptions {
    ClientOptions::secured(ClientSecurity {
        token: token_value.map(token),
        tls: None,
    })
}

/// The code of each protected call: learner status, checkpoint, weight stream, selector status.
async fn codes(cluster: &Cluster, options: ClientOptions) -> [Code; 4] {
    let code = |r: Result<(), Status>| r.err().map_or(Code::Ok, |s| s.code());
    let learner = cluster.learner.to_string();
    let mut l = connect_learner_with(&learner, options.clone())
        .await
        .unwrap();
    let status = code(
        l.status()
            .await
            .map(|s| assert_eq!(s.run_id, "secured-run")),
    );
    let checkpoint = code(
        l.save_checkpoint(CheckpointRequest::default())
            .await
            .map(drop),
    );
    let stream = code(match l.watch_weights(&[WeightsKind::Policy]).await {
        Ok(mut s) => {
            let w = tokio::time::timeout(WAIT, s.next())
                .await
                .expect("a weights message within 10 s")
                .expect("stream open")
                .expect("valid weights");
            assert_eq!(w.version(), 1);
            Ok(())
        }
        Err(status) => Err(status),
    });
    let mut s = connect_selector_with(&cluster.selector.to_string(), options)
        .await
        .unwrap();
    let selector = code(
        s.status()
            .await
            .map(|s| assert_eq!(s.run_id, "secured-run")),
    );
    [status, checkpoint, stream, selector]
}

fn locked(status_without_token: bool) -> ServerSecurity {
    ServerSecurity {
        token: Some(token(TOKEN)),
        status_without_token,
        tls: None,
    }
}

fn hub_with_weights() -> WeightHub {
    let hub = WeightHub::new();
    hub.publish(&weights(1)).unwrap();
    hub
}

/// Health `Check` and a reflection listing over a raw channel with the given token.
async fn health_and_reflection(addr: SocketAddr, token_value: Option<&str>) -> (Code, Code) {
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let with_token = |mut r: tonic::Request<()>| {
        if let Some(t) = token_value {
            r.metadata_mut()
                .insert("authorization", format!("Bearer {t}").parse().unwrap());
        }
        Ok(r)
    };
    let mut health = tonic_health::pb::health_client::HealthClient::with_interceptor(
        channel.clone(),
        with_token,
    );
    let health_code = match health
        .check(tonic_health::pb::HealthCheckRequest::default())
        .await
    {
        Ok(_) => Code::Ok,
        Err(s) => s.code(),
    };
    use tonic_reflection::pb::v1::{
        server_reflection_client::ServerReflectionClient, server_reflection_request,
        ServerReflectionRequest,
    };
    let mut reflection = ServerReflectionClient::with_interceptor(channel, with_token);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(server_reflection_request::MessageRequest::ListServices(
            String::new(),
        )),
    };
    let reflection_code = match reflection
        .server_reflection_info(futures_util::stream::iter([request]))
        .await
    {
        Ok(response) => match response.into_inner().next().await {
            Some(Ok(_)) => Code::Ok,
            Some(Err(s)) => s.code(),
            None => Code::Unknown,
        },
        Err(s) => s.code(),
    };
    (health_code, reflection_code)
}

const UNAUTH: [Code; 4] = [Code::Unauthenticated; 4];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_token_every_rpc_is_unauthenticated_the_weight_stream_included() {
    let cluster = Cluster::start(locked(false), hub_with_weights()).await;
    assert_eq!(codes(&cluster, client(None)).await, UNAUTH);
    assert_eq!(
        health_and_reflection(cluster.learner, None).await,
        (Code::Unauthenticated, Code::Unauthenticated)
    );
    // The message says how to provide one.
    let mut l = connect_learner_with(&cluster.learner.to_string(), client(None))
        .await
        .unwrap();
    let message = l.status().await.unwrap_err().message().to_owned();
    assert!(message.contains("TERL_TOKEN"), "{message}");
    cluster.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_token_is_unauthenticated() {
    let cluster = Cluster::start(locked(false), hub_with_weights()).await;
    assert_eq!(codes(&cluster, client(Some(WRONG))).await, UNAUTH);
    // A prefix or an extension of the right token is wrong too.
    let longer = format!("{TOKEN}x");
    assert_eq!(codes(&cluster, client(Some(&longer))).await, UNAUTH);
    assert_eq!(
        codes(&cluster, client(Some(&TOKEN[..TOKEN.len() - 1]))).await,
        UNAUTH
    );
    assert_eq!(
        health_and_reflection(cluster.learner, Some(WRONG)).await,
        (Code::Unauthenticated, Code::Unauthenticated)
    );
    cluster.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_right_token_opens_status_checkpoint_weights_health_and_reflection() {
    let cluster = Cluster::start(locked(false), hub_with_weights()).await;
    assert_eq!(codes(&cluster, client(Some(TOKEN))).await, [Code::Ok; 4]);
    assert_eq!(
        health_and_reflection(cluster.learner, Some(TOKEN)).await,
        (Code::Ok, Code::Ok)
    );
    cluster.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_without_token_opens_status_and_health_only() {
    let cluster = Cluster::start(locked(true), hub_with_weights()).await;
    let [status, checkpoint, stream, selector] = codes(&cluster, client(None)).await;
    assert_eq!(
        (status, checkpoint, stream, selector),
        (
            Code::Ok,
            Code::Unauthenticated,
            Code::Unauthenticated,
            Code::Ok
        )
    );
    assert_eq!(
        health_and_reflection(cluster.learner, None).await,
        (Code::Ok, Code::Unauthenticated)
    );
    assert_eq!(codes(&cluster, client(Some(TOKEN))).await, [Code::Ok; 4]);
    cluster.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_token_the_server_serves_loopback_only() {
    let open = ServerSecurity::default();
    // Refused before anything is bound...
    let err = bind_secured("0.0.0.0:0".parse().unwrap(), &open)
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("TERL_TOKEN"), "{err}");
    assert!(err.contains("cluster.token_file"), "{err}");
    // ...and by the server itself when handed such a listener.
    let listener = TcpListener::bind("0.0.0.0:0").await.unwrap();
    let result = tokio::time::timeout(
        WAIT,
        serve_learner_with(
            listener,
            TestLearner {
                hub: WeightHub::new(),
            },
            std::future::pending(),
            ServeOptions::default(),
        ),
    )
    .await
    .expect("refuses at once");
    let err = result.unwrap_err();
    assert!(matches!(err, ServeError::Security(_)), "{err:?}");
    assert!(err.to_string().contains("cluster.token_file"), "{err}");
    // With a token the same bind serves, and the token is checked.
    let cluster = Cluster::start_on("0.0.0.0:0", locked(false), hub_with_weights()).await;
    assert_eq!(codes(&cluster, client(Some(TOKEN))).await, [Code::Ok; 4]);
    assert_eq!(codes(&cluster, client(None)).await, UNAUTH);
    cluster.stop().await;
    // Loopback without a token is the default and works.
    let cluster = Cluster::start(open, hub_with_weights()).await;
    assert_eq!(codes(&cluster, client(None)).await, [Code::Ok; 4]);
    cluster.stop().await;
}

/// A CA and a certificate for `localhost` and `127.0.0.1` signed by it, written to `dir`
/// ([`terl_wire::certs::write_run_certificates`], as `terl certs` makes them):
/// (ca.pem, cert.pem, key.pem).
fn make_certificates(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let files = terl_wire::certs::write_run_certificates(
        dir,
        "terl test",
        &["localhost".to_owned(), "127.0.0.1".to_owned()],
    )
    .unwrap();
    (files.ca, files.cert, files.key)
}

fn temp_dir(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("terl-security-{name}-{}", std::process::id()))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_with_a_generated_certificate_works_and_plaintext_or_a_wrong_ca_fails() {
    let dir = temp_dir("tls");
    let (ca, cert, key) = make_certificates(&dir.join("good"));
    let (other_ca, _, _) = make_certificates(&dir.join("other"));
    let security = ServerSecurity {
        tls: Some(ServerTls::from_files(&cert, &key).unwrap()),
        ..locked(false)
    };
    let cluster = Cluster::start(security, hub_with_weights()).await;
    let tls_client = |ca: &Path, domain: Option<&str>, token_value: Option<&str>| {
        ClientOptions::secured(ClientSecurity {
            token: token_value.map(token),
            tls: Some(ClientTls::from_file(ca, domain.map(str::to_owned)).unwrap()),
        })
    };
    // Verified against the CA, by IP address and by name; the token is still required.
    assert_eq!(
        codes(&cluster, tls_client(&ca, None, Some(TOKEN))).await,
        [Code::Ok; 4]
    );
    let by_name = format!("localhost:{}", cluster.learner.port());
    let mut l = connect_learner_with(&by_name, tls_client(&ca, None, Some(TOKEN)))
        .await
        .unwrap();
    assert_eq!(l.status().await.unwrap().run_id, "secured-run");
    assert_eq!(
        codes(&cluster, tls_client(&ca, None, None)).await,
        UNAUTH,
        "TLS does not replace the token"
    );

    // A plaintext client gets nowhere.
    let learner = cluster.learner.to_string();
    let plaintext = async {
        let mut l = connect_learner_with(&learner, client(Some(TOKEN)))
            .await
            .map_err(|e| e.to_string())?;
        l.status().await.map_err(|s| s.to_string())
    };
    let refused = tokio::time::timeout(WAIT, plaintext).await.unwrap();
    assert!(refused.is_err(), "{refused:?}");
    // A client that trusts another CA refuses the server's certificate.
    let wrong_ca = connect_learner_with(&learner, tls_client(&other_ca, None, Some(TOKEN))).await;
    assert!(
        matches!(wrong_ca, Err(ConnectError::Connect { .. })),
        "{wrong_ca:?}"
    );
    // ...and so does one expecting a name the certificate does not hold.
    let wrong_name = connect_learner_with(
        &learner,
        tls_client(&ca, Some("learner.elsewhere"), Some(TOKEN)),
    )
    .await;
    assert!(wrong_name.is_err());
    // A TLS client never falls back to plaintext for an http:// address.
    let http = connect_learner_with(
        &format!("http://{learner}"),
        tls_client(&ca, None, Some(TOKEN)),
    )
    .await;
    assert!(
        matches!(http, Err(ConnectError::PlaintextWithTls { .. })),
        "{http:?}"
    );
    cluster.stop().await;
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Collects everything `tracing` writes, at every level.
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<u8>>>);

impl Write for Captured {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for Captured {
    type Writer = Captured;
    fn make_writer(&'a self) -> Captured {
        self.clone()
    }
}

/// Runs `f` on a current-thread runtime (so every task logs into the captured subscriber) with
/// TRACE logging of every crate (tonic, h2, hyper, rustls included).
fn with_captured_logs<F: Future<Output = ()>>(f: impl FnOnce() -> F) -> String {
    let captured = Captured::default();
    let subscriber = tracing_subscriber::fmt()
        .with_max_level(tracing::Level::TRACE)
        .with_writer(captured.clone())
        .with_ansi(false)
        .finish();
    {
        let _guard = tracing::subscriber::set_default(subscriber);
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
            .block_on(f());
    }
    let bytes = captured.0.lock().unwrap().clone();
    String::from_utf8_lossy(&bytes).into_owned()
}

#[test]
fn the_token_appears_in_no_log_line_and_no_debug_output() {
    let dir = temp_dir("logs");
    let (ca, cert, key) = make_certificates(&dir);
    let token_file = dir.join("token");
    std::fs::write(&token_file, format!("{TOKEN}\n")).unwrap();
    let mut debug_output = String::new();
    let debug = &mut debug_output;
    let (ca, cert, key, token_file) = (&ca, &cert, &key, &token_file);
    let logs = with_captured_logs(|| async move {
        for tls in [false, true] {
            let security = ServerSecurity {
                token: Some(Token::from_file(token_file).unwrap()),
                status_without_token: false,
                tls: tls.then(|| ServerTls::from_files(cert, key).unwrap()),
            };
            let cluster = Cluster::start(security.clone(), hub_with_weights()).await;
            let options = |t: &str| {
                ClientOptions::secured(ClientSecurity {
                    token: Some(token(t)),
                    tls: tls.then(|| ClientTls::from_file(ca, None).unwrap()),
                })
            };
            assert_eq!(codes(&cluster, options(TOKEN)).await, [Code::Ok; 4]);
            assert_eq!(codes(&cluster, options(WRONG)).await, UNAUTH);
            let client = connect_learner_with(&cluster.learner.to_string(), options(TOKEN))
                .await
                .unwrap();
            *debug += &format!(
                "{security:?}\n{:?}\n{:?}\n{client:?}\n",
                ServeOptions {
                    security: security.clone(),
                    ..ServeOptions::default()
                },
                options(TOKEN)
            );
            cluster.stop().await;
        }
    });
    // The capture works: the servers' start-up lines and the refusals are there.
    assert!(logs.contains("gRPC server listening"), "{logs}");
    assert!(logs.contains("call refused"), "no refusal logged");
    for secret in [TOKEN, WRONG] {
        assert!(!logs.contains(secret), "token in the logs");
        assert!(
            !debug_output.contains(secret),
            "token in Debug: {debug_output}"
        );
    }
    assert!(debug_output.contains("redacted"), "{debug_output}");
    // The private key is not in Debug either.
    let key_pem = std::fs::read_to_string(key).unwrap();
    let key_body = key_pem.lines().nth(1).unwrap();
    assert!(!debug_output.contains(key_body));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn raw_grpc_without_terl_clients_gets_unauthenticated_for_a_malformed_header() {
    // A header that is not `Bearer <token>` (e.g. the bare token) is refused like a wrong one.
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(async {
            let cluster = Cluster::start(locked(false), hub_with_weights()).await;
            let channel =
                tonic::transport::Endpoint::from_shared(format!("http://{}", cluster.learner))
                    .unwrap()
                    .connect()
                    .await
                    .unwrap();
            let mut raw = pb::learner_client::LearnerClient::with_interceptor(
                channel,
                |mut r: tonic::Request<()>| {
                    r.metadata_mut()
                        .insert("authorization", TOKEN.parse().unwrap());
                    Ok(r)
                },
            );
            let code = raw
                .get_status(pb::GetLearnerStatusRequest {})
                .await
                .unwrap_err()
                .code();
            assert_eq!(code, Code::Unauthenticated);
            cluster.stop().await;
        });
}
