//! A wall started by hand the way deploy/README.md describes (serve + issue-cert + nodes), with
//! hostile peers knocking, a peer from another CA, and a render node killed mid-run.

use std::path::Path;
use std::time::Duration;
use tessera_net::cluster::{ClusterCa, NodeIdentity};
use tessera_net::framed::{read_msg, write_msg};
use tessera_net::quic;
use tessera_protocol::{FromNode, Hello, Role, ToNode, PROTOCOL_VERSION};
use tessera_tests::*;

/// Hostile and foreign peers, in-process. Returns what each attempt ended with.
async fn knock(master: std::net::SocketAddr, cluster: &Path, foreign: &Path) -> Vec<String> {
    let mut seen = Vec::new();
    let ours = NodeIdentity::load(&cluster.join("intruder")).unwrap();
    let endpoint = quic::endpoint("127.0.0.1:0".parse().unwrap(), &ours, false).unwrap();

    // An absurd length prefix: refused before any allocation, connection closed.
    let conn = quic::connect(&endpoint, master, "master").await.unwrap();
    let (mut send, mut recv) = conn.open_bi().await.unwrap();
    send.write_all(&u32::MAX.to_le_bytes()).await.unwrap();
    let r = tokio::time::timeout(Duration::from_secs(10), read_msg::<ToNode>(&mut recv)).await;
    seen.push(format!("oversized: {r:?}"));

    // Random bytes in a plausible frame.
    let conn = quic::connect(&endpoint, master, "master").await.unwrap();
    let (mut send, mut recv) = conn.open_bi().await.unwrap();
    let mut junk = 200u32.to_le_bytes().to_vec();
    junk.extend((0..200u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8));
    send.write_all(&junk).await.unwrap();
    let r = tokio::time::timeout(Duration::from_secs(10), read_msg::<ToNode>(&mut recv)).await;
    seen.push(format!("random: {r:?}"));

    // A truncated message, then the stream ends.
    let conn = quic::connect(&endpoint, master, "master").await.unwrap();
    let (mut send, mut recv) = conn.open_bi().await.unwrap();
    send.write_all(&[50, 0, 0, 0, 1, 2, 3]).await.unwrap();
    send.finish().unwrap();
    let r = tokio::time::timeout(Duration::from_secs(10), read_msg::<ToNode>(&mut recv)).await;
    seen.push(format!("truncated: {r:?}"));

    // The wrong protocol version gets a clear refusal.
    let conn = quic::connect(&endpoint, master, "master").await.unwrap();
    let (mut send, mut recv) = conn.open_bi().await.unwrap();
    let hello = FromNode::Hello(Hello {
        version: PROTOCOL_VERSION + 1,
        role: Role::Render { cores: 1 },
        host: "future".into(),
    });
    write_msg(&mut send, &hello).await.unwrap();
    let r = tokio::time::timeout(Duration::from_secs(10), read_msg::<ToNode>(&mut recv)).await;
    seen.push(format!("version: {r:?}"));

    // A certificate from another CA, even one that trusts our CA, is refused by the master.
    let mut theirs = NodeIdentity::load(&foreign.join("stranger")).unwrap();
    theirs.ca = ours.ca.clone();
    let endpoint = quic::endpoint("127.0.0.1:0".parse().unwrap(), &theirs, false).unwrap();
    let r = match quic::connect(&endpoint, master, "master").await {
        Ok(conn) => {
            let opened = async {
                let (mut send, mut recv) = conn
                    .open_bi()
                    .await
                    .map_err(|e| tessera_net::NetError::StreamBroken(e.to_string()))?;
                let hello = FromNode::Hello(Hello {
                    version: PROTOCOL_VERSION,
                    role: Role::Render { cores: 1 },
                    host: "stranger".into(),
                });
                write_msg(&mut send, &hello).await?;
                read_msg::<ToNode>(&mut recv).await
            };
            format!(
                "{:?}",
                tokio::time::timeout(Duration::from_secs(10), opened).await
            )
        }
        Err(e) => format!("Err({e:#})"),
    };
    seen.push(format!("foreign: {r}"));
    seen
}

#[test]
fn serve_wall_survives_hostile_peers_and_a_dead_render_node() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let foreign = dir.path().join("foreign-cluster");
    let out = dir.path().join("serve-out");
    let (d0, d1, r0, r1) = (
        issue_cert(&cluster, "display-0"),
        issue_cert(&cluster, "display-1"),
        issue_cert(&cluster, "render-0"),
        issue_cert(&cluster, "render-1"),
    );
    issue_cert(&cluster, "intruder");
    ClusterCa::open_or_create(&foreign)
        .unwrap()
        .issue("stranger", &foreign.join("stranger"), None)
        .unwrap();

    let wall = ["--wall", "2x1", "--screen", "320x180"];
    let mut args = vec![
        "serve",
        "--listen",
        // Port 0: the kernel picks a free port, and the master says which.
        "127.0.0.1:0",
        "--cluster-dir",
        cluster.to_str().unwrap(),
        "--render-nodes",
        "2",
    ];
    args.extend(wall);
    args.extend([
        "--frames",
        "0",
        "--save-frame",
        "3",
        "--out",
        out.to_str().unwrap(),
    ]);
    let master = Proc::start("tessera-master", &args);
    let listening = master.wait_for_stderr("listening on", Duration::from_secs(60));
    let addr = listening
        .rsplit(' ')
        .next()
        .expect("an address at the end of the line")
        .to_string();

    let rt = tokio::runtime::Runtime::new().unwrap();
    let seen = rt.block_on(knock(addr.parse().unwrap(), &cluster, &foreign));
    assert!(!seen[0].contains("Ok(Ok(Some"), "{seen:?}");
    assert!(!seen[1].contains("Ok(Ok(Some"), "{seen:?}");
    assert!(!seen[2].contains("Ok(Ok(Some"), "{seen:?}");
    assert!(
        seen[3].contains("Refused") && seen[3].contains("protocol version"),
        "{seen:?}"
    );
    assert!(
        !seen[4].contains("Welcome") && (seen[4].contains("Err")),
        "{seen:?}"
    );

    // A render node holding another CA's certificate cannot join either.
    let stranger = run(
        "tessera-render-node",
        &[
            "--master",
            &addr,
            "--cert-dir",
            foreign.join("stranger").to_str().unwrap(),
        ],
        Duration::from_secs(30),
    );
    assert!(!stranger.status.success());
    assert!(
        stranger.stderr.contains("cannot connect to the master"),
        "{}",
        stranger.stderr
    );

    // A render node's certificate cannot join as display 0, nor display 1's as display 0.
    for (certs, why) in [(&r0, "render"), (&d1, "another display")] {
        let impostor = run(
            "tessera-display-node",
            &[
                "--master",
                &addr,
                "--display",
                "0",
                "--cert-dir",
                certs,
                "--listen",
                "127.0.0.1:0",
            ],
            Duration::from_secs(30),
        );
        assert!(!impostor.status.success(), "{}", impostor.stderr);
        assert!(
            impostor
                .stderr
                .contains(&format!("certificate is for {why}")),
            "{}",
            impostor.stderr
        );
    }

    let _displays = [
        Proc::start(
            "tessera-display-node",
            &[
                "--master",
                &addr,
                "--display",
                "0",
                "--cert-dir",
                &d0,
                "--listen",
                "127.0.0.1:0",
                "--out",
                out.to_str().unwrap(),
            ],
        ),
        Proc::start(
            "tessera-display-node",
            &[
                "--master",
                &addr,
                "--display",
                "1",
                "--cert-dir",
                &d1,
                "--listen",
                "127.0.0.1:0",
                "--out",
                out.to_str().unwrap(),
            ],
        ),
    ];
    let _survivor = Proc::start(
        "tessera-render-node",
        &["--master", &addr, "--cert-dir", &r0, "--threads", "1"],
    );
    let victim = Proc::start(
        "tessera-render-node",
        &["--master", &addr, "--cert-dir", &r1, "--threads", "1"],
    );
    // Frame 3 saved means frames are flowing; then kill a render node in the middle of it all.
    assert!(
        wait_for(Duration::from_secs(60), || out
            .join("display-1.png")
            .exists()),
        "the wall never started"
    );
    victim.signal(libc::SIGKILL);
    drop(victim);
    // The master noticed the death and gave its tiles away: now interrupt.
    master.wait_for_stderr(
        "its tiles go to the other render nodes",
        Duration::from_secs(60),
    );
    master.signal(libc::SIGINT);
    let o = master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    assert!(
        o.stderr.contains("refused"),
        "the master logs refusals:\n{}",
        o.stderr
    );
    assert!(
        o.stderr.contains("its tiles go to the other render nodes"),
        "{}",
        o.stderr
    );

    let report = read_json(&out.join("report.json"));
    assert_eq!(report["render_nodes_lost"], 1);
    let frames = report["frames"].as_u64().unwrap();
    assert!(frames > 3);
    for d in report["displays"].as_array().unwrap() {
        assert_eq!(d["frames_presented"].as_u64().unwrap(), frames, "{d}");
    }
    let survivor_stats = &report["render_nodes"].as_array().unwrap();
    assert_eq!(survivor_stats.len(), 1, "only the survivor reports");
    assert!(wall_png_exists(&out));
}

fn wall_png_exists(out: &Path) -> bool {
    out.join("wall.png").exists()
}
