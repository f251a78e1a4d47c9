//! The messages' checks on arrival and their round trips.
use super::*;
use tessera_model::wall::TileId;

#[test]
fn ranges_merge_consecutive_ids() {
    let r = to_ranges([1, 2, 3, 7, 8, 10].map(TileId));
    assert_eq!(
        r,
        vec![
            TileRange { start: 1, end: 4 },
            TileRange { start: 7, end: 9 },
            TileRange { start: 10, end: 11 }
        ]
    );
    let back: Vec<u32> = r.iter().flat_map(|r| r.tiles()).map(|t| t.0).collect();
    assert_eq!(back, vec![1, 2, 3, 7, 8, 10]);
}

fn decode_err<T: serde::de::DeserializeOwned + std::fmt::Debug>(raw: &impl Serialize) -> String {
    let bytes = postcard::to_allocvec(raw).unwrap();
    codec::decode::<T>(&bytes).unwrap_err().to_string()
}

#[test]
fn backward_tile_ranges_from_the_wire_are_refused() {
    #[derive(Serialize)]
    struct Raw(u32, u32);
    let err = decode_err::<TileRange>(&Raw(9, 3));
    assert!(err.contains("9..3"), "{err}");
    assert!(TileRange::new(3, 3).unwrap().is_empty());
}

#[test]
fn a_session_naming_displays_the_wall_lacks_is_refused() {
    let wall = WallLayout::grid(2, 1, 64, 64).unwrap();
    let endpoint = |d| DisplayEndpoint {
        display: DisplayId(d),
        addr: "127.0.0.1:9".parse().unwrap(),
    };
    let spec = |displays| SessionSpec {
        wall: wall.clone(),
        scene: SceneSpec::Gallery,
        scene_hash: [0; 32],
        displays,
        save_frame: None,
        compression: pixels::Compression::None,
        windows: BTreeMap::new(),
        data: dsm::DataSpec::Replicated,
        particle_range: None,
    };
    assert!(Session::new(spec(vec![endpoint(0), endpoint(1)])).is_ok());
    assert_eq!(
        Session::new(spec(vec![endpoint(2)])),
        Err(ProtocolError::UnknownDisplay {
            display: 2,
            count: 2
        })
    );
    assert_eq!(
        Session::new(spec(vec![endpoint(1), endpoint(1)])),
        Err(ProtocolError::DuplicateDisplay(1))
    );
    let err = decode_err::<Session>(&spec(vec![endpoint(5)]));
    assert!(err.contains("display 5"), "{err}");
}

#[test]
fn a_session_whose_particle_range_is_not_finite_or_backward_is_refused() {
    let spec = |range| SessionSpec {
        wall: WallLayout::grid(1, 1, 64, 64).unwrap(),
        scene: SceneSpec::Gallery,
        scene_hash: [0; 32],
        displays: Vec::new(),
        save_frame: None,
        compression: pixels::Compression::None,
        windows: BTreeMap::new(),
        data: dsm::DataSpec::Replicated,
        particle_range: Some(range),
    };
    let session = Session::new(spec([-2.0, 2.0])).unwrap();
    assert_eq!(session.particle_range(), Some([-2.0, 2.0]));
    assert!(Session::new(spec([3.0, 3.0])).is_ok(), "one value");
    for bad in [[2.0, 1.0], [f32::NAN, 1.0], [0.0, f32::INFINITY]] {
        assert!(
            matches!(
                Session::new(spec(bad)),
                Err(ProtocolError::BadParticleRange { .. })
            ),
            "{bad:?}"
        );
    }
    let err = decode_err::<Session>(&spec([5.0, -5.0]));
    assert!(err.contains("particle range 5..-5"), "{err}");
}

#[test]
fn a_hello_with_absurd_fields_is_refused() {
    let hello = |role, host: &str| HelloRaw2 {
        version: PROTOCOL_VERSION,
        role,
        host: host.to_string(),
    };
    #[derive(Serialize)]
    struct HelloRaw2 {
        version: u32,
        role: Role,
        host: String,
    }
    let err = decode_err::<Hello>(&hello(Role::Render { cores: 0 }, "a"));
    assert!(err.contains("0 cores"), "{err}");
    let err = decode_err::<Hello>(&hello(Role::Render { cores: 1 }, &"h".repeat(300)));
    assert!(err.contains("host name"), "{err}");
    let err = decode_err::<Hello>(&hello(Role::Render { cores: 1 }, "evil\u{1b}[2J"));
    assert!(err.contains("host name"), "{err}");
}

#[test]
fn stats_with_nan_seconds_are_refused() {
    #[derive(Serialize)]
    struct Raw(
        u64,
        u64,
        f64,
        f64,
        Vec<f64>,
        u64,
        u64,
        f64,
        u64,
        Option<Box<dsm::DsmStats>>,
    );
    let raw = |busy, loads, dsm| Raw(1, 2, busy, 1.0, loads, 0, 0, 0.0, 0, dsm);
    let err = decode_err::<RenderStats>(&raw(f64::NAN, vec![], None));
    assert!(err.contains("busy_s"), "{err}");
    let err = decode_err::<RenderStats>(&raw(1.0, vec![0.5, -1.0], None));
    assert!(err.contains("volume_load_s"), "{err}");
    let many = vec![0.1; MAX_REPORTED_LOADS + 1];
    let err = decode_err::<RenderStats>(&raw(1.0, many, None));
    assert!(err.contains("too many"), "{err}");
    let bad = dsm::DsmStats {
        latency_p99_us: f64::INFINITY,
        ..dsm::DsmStats::default()
    };
    let err = decode_err::<RenderStats>(&raw(1.0, vec![], Some(Box::new(bad))));
    assert!(err.contains("latency_p99_us"), "{err}");
}
