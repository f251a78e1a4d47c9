//! Point clouds: positions only, drawn as particles. A PLY file with a `vertex` element and no
//! faces (no `face` element, or one of 0 rows) is a point cloud, as is a CSV file with `x`,
//! `y`, `z` and no `radius` column ([`super::particles`]).
//!
//! A point has no size, so the spheres get one from the data: half the median distance from a
//! point to its nearest neighbour (spheres that just touch along a scanned surface), measured
//! on up to 4096 points spread through the file. The attribute, which the colour map colours,
//! is a PLY `intensity`, `scalar` or `value` property when there is one, else the height (y,
//! the renderer's up).

use super::files::{file_error, in_range};
use super::particles::{self, WorldParticle};
use super::SceneError;
use glam::DVec3;
use std::path::Path;

/// The PLY vertex properties taken as the attribute, first found first.
const SCALARS: [&str; 3] = ["intensity", "scalar", "value"];
/// How many points the nearest-neighbour spacing is measured on.
const SAMPLES: usize = 4096;

/// Whether `path` is a PLY file with vertices and no faces: a point cloud, not a mesh. A
/// header that cannot be read says no (the mesh loader then names what is wrong).
pub fn is_point_cloud(path: &Path) -> bool {
    let is_ply = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"));
    is_ply
        && ply_header(path).is_ok_and(|(_, header)| {
            header.elements.contains_key("vertex")
                && header.elements.get("face").is_none_or(|f| f.count == 0)
        })
}

/// Reads a particle file (`.csv`, `.tpart`) or a PLY point cloud.
///
/// # Errors
/// A [`SceneError`] naming the file and the line, record or vertex at fault.
pub fn load(path: &Path) -> Result<Vec<WorldParticle>, SceneError> {
    if is_point_cloud(path) {
        load_ply(path)
    } else {
        particles::load_particles(path)
    }
}

/// Spheres at `centres`, sized by their spacing ([`spacing_radius`]); their attribute is
/// `attributes` where given, else the height (y).
pub fn from_positions(centres: &[DVec3], attributes: Option<&[f32]>) -> Vec<WorldParticle> {
    let radius = spacing_radius(centres);
    let attribute = |i: usize| match attributes {
        Some(a) => Some(a[i]).filter(|a| a.is_finite()).unwrap_or(f32::NAN),
        None => centres[i].y as f32,
    };
    let spheres = centres
        .iter()
        .enumerate()
        .map(|(i, &center)| WorldParticle {
            center,
            radius,
            attribute: attribute(i),
        });
    spheres.collect()
}

/// Half the median nearest-neighbour distance of (a spread sample of) `centres`: spheres that
/// just touch their neighbours. Points are bucketed in a grid whose cells are shrunk until
/// they hold 8 points on average, so that a surface (whose spacing is far below a volume's
/// for the same count and box) is measured as finely as a volume; the neighbours are sought
/// in the 27 cells around each sampled point. 0.5 when there is no spacing to measure (one
/// point, or all at one place).
pub fn spacing_radius(centres: &[DVec3]) -> f32 {
    let lo = centres.iter().fold(DVec3::INFINITY, |m, &p| m.min(p));
    let hi = centres.iter().fold(DVec3::NEG_INFINITY, |m, &p| m.max(p));
    let diagonal = (hi - lo).length();
    if centres.len() < 2 || diagonal.is_nan() || diagonal <= 0.0 || diagonal.is_infinite() {
        return 0.5;
    }
    let n = centres.len();
    let mut cell = diagonal / (n as f64).cbrt();
    let mut grid = Grid::new(centres, lo, cell);
    for _ in 0..16 {
        if n <= 8 * grid.occupied {
            break;
        }
        cell /= 2.0;
        grid = Grid::new(centres, lo, cell);
    }
    let step = n.div_ceil(SAMPLES);
    let mut nearest: Vec<f64> = (0..n)
        .step_by(step)
        .filter_map(|i| grid.nearest(centres, i))
        .collect();
    if nearest.is_empty() {
        return (cell / 2.0) as f32;
    }
    let middle = nearest.len() / 2;
    let (_, median, _) = nearest.select_nth_unstable_by(middle, f64::total_cmp);
    (*median / 2.0) as f32
}

/// Points bucketed by grid cell: (cell key, point index), sorted by key.
struct Grid {
    lo: DVec3,
    cell: f64,
    keyed: Vec<(u64, u32)>,
    occupied: usize,
}

impl Grid {
    fn new(centres: &[DVec3], lo: DVec3, cell: f64) -> Grid {
        let mut grid = Grid {
            lo,
            cell,
            keyed: Vec::new(),
            occupied: 0,
        };
        grid.keyed = (0..centres.len())
            .map(|i| (grid.key(grid.coords(centres[i])), i as u32))
            .collect();
        grid.keyed.sort_unstable();
        grid.occupied = 1 + grid.keyed.windows(2).filter(|w| w[0].0 != w[1].0).count();
        grid
    }

    fn coords(&self, p: DVec3) -> [i64; 3] {
        ((p - self.lo) / self.cell).floor().as_i64vec3().to_array()
    }

    /// 21 bits an axis; cells past that (a grid over 2 million cells wide) share keys,
    /// which only makes the search look at more points.
    fn key(&self, c: [i64; 3]) -> u64 {
        let axis = |v: i64| (v.clamp(0, (1 << 21) - 1)) as u64;
        axis(c[0]) << 42 | axis(c[1]) << 21 | axis(c[2])
    }

    /// The distance from point `i` to its nearest other point at a different place, among
    /// the 27 cells around it (at most 512 points looked at, so a pile of duplicates stays
    /// cheap); None when there is none there.
    fn nearest(&self, centres: &[DVec3], i: usize) -> Option<f64> {
        let p = centres[i];
        let [x, y, z] = self.coords(p);
        let mut best = f64::INFINITY;
        let mut looked = 0;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let key = self.key([x + dx, y + dy, z + dz]);
                    let start = self.keyed.partition_point(|&(k, _)| k < key);
                    for &(k, j) in &self.keyed[start..] {
                        if k != key || looked >= 512 {
                            break;
                        }
                        looked += 1;
                        let d = centres[j as usize].distance(p);
                        if d > 0.0 && d < best {
                            best = d;
                        }
                    }
                }
            }
        }
        best.is_finite().then_some(best)
    }
}

/// A point-cloud vertex row: its position and the candidate attribute properties.
#[derive(Default)]
struct PointRow {
    xyz: [Option<f64>; 3],
    scalars: [Option<f64>; 3],
}

impl ply_rs_bw::ply::PropertyAccess for PointRow {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(
        &mut self,
        name: &str,
        property: ply_rs_bw::ply::Property,
    ) -> ply_rs_bw::ply::PropertyAccessResult {
        use ply_rs_bw::ply::{Property as P, PropertyAccessResult as R};
        let slot = match (name, SCALARS.iter().position(|&s| s == name)) {
            ("x", _) => &mut self.xyz[0],
            ("y", _) => &mut self.xyz[1],
            ("z", _) => &mut self.xyz[2],
            (_, Some(k)) => &mut self.scalars[k],
            _ => return R::Ignored,
        };
        *slot = match property {
            P::Char(v) => Some(f64::from(v)),
            P::UChar(v) => Some(f64::from(v)),
            P::Short(v) => Some(f64::from(v)),
            P::UShort(v) => Some(f64::from(v)),
            P::Int(v) => Some(f64::from(v)),
            P::UInt(v) => Some(f64::from(v)),
            P::Float(v) => Some(f64::from(v)),
            P::Double(v) => Some(v),
            _ => return R::UnsupportedType,
        };
        R::Set
    }
}

type PlyReader = ply_rs_bw::parser::Reader<std::io::BufReader<std::fs::File>>;

fn ply_header(path: &Path) -> Result<(PlyReader, ply_rs_bw::ply::Header), String> {
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let mut reader = ply_rs_bw::parser::Reader::new(std::io::BufReader::new(file));
    let parser = ply_rs_bw::parser::Parser::<PointRow>::new();
    let header = parser.read_header(&mut reader).map_err(|e| {
        format!(
            "not a valid PLY file: {}",
            e.to_string().replace(['\n', '\t'], " ")
        )
    })?;
    Ok((reader, header))
}

/// A PLY point cloud's vertices as spheres.
fn load_ply(path: &Path) -> Result<Vec<WorldParticle>, SceneError> {
    let err = |message: String| file_error(path, message);
    let (mut reader, header) = ply_header(path).map_err(err)?;
    let ascii = header.encoding == ply_rs_bw::ply::Encoding::Ascii;
    // Every row takes at least a byte: a larger count is a lie, refused before allocating.
    let file_bytes = std::fs::metadata(path).map_or(u64::MAX, |m| m.len());
    for (name, def) in &header.elements {
        if def.count as u64 > file_bytes {
            return Err(err(format!(
                "element `{name}` claims {} rows, more than the file's {file_bytes} bytes hold",
                def.count
            )));
        }
    }
    let vertex = &header.elements["vertex"];
    if let Some(p) = ["x", "y", "z"]
        .iter()
        .find(|p| !vertex.properties.contains_key(**p))
    {
        return Err(err(format!("the `vertex` element has no `{p}` property")));
    }
    let scalar = SCALARS
        .iter()
        .position(|s| vertex.properties.contains_key(*s));
    let parser = ply_rs_bw::parser::Parser::<PointRow>::new();
    let mut rows = None;
    for (name, def) in &header.elements {
        let first_line = reader.line().max(1);
        let read = parser
            .read_payload_for_element(&mut reader, def, &header)
            .map_err(|e| {
                let text = e.to_string().replace(['\n', '\t'], " ");
                match e.line().filter(|&l| l >= first_line) {
                    Some(l) if ascii => {
                        err(format!("{name} {} (line {l}): {text}", l - first_line))
                    }
                    _ => err(format!("element `{name}`: {text}")),
                }
            })?;
        if name == "vertex" {
            rows = Some((read, first_line));
            break;
        }
    }
    let (rows, first_line) = rows.unwrap_or_default();
    let mut centres = Vec::with_capacity(rows.len());
    let mut attributes = Vec::new();
    for (index, row) in rows.iter().enumerate() {
        let at = || match ascii {
            true => format!("vertex {index} (line {})", first_line + index),
            false => format!("vertex {index}"),
        };
        let [Some(x), Some(y), Some(z)] = row.xyz else {
            return Err(err(format!("{} lacks one of x, y, z", at())));
        };
        let p = DVec3::new(x, y, z);
        if !in_range(p) {
            return Err(err(format!("{} has a non-finite coordinate {p}", at())));
        }
        centres.push(p);
        if let Some(k) = scalar {
            attributes.push(row.scalars[k].map_or(f32::NAN, |v| v as f32));
        }
    }
    let attributes = scalar.map(|_| &attributes[..]);
    Ok(from_positions(&centres, attributes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use tessera_model::scene_spec::SceneSpec;

    fn load_scene(dir: &Path, name: &str, bytes: &[u8]) -> Result<Scene, String> {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        let spec = SceneSpec::File(path);
        Scene::load(&spec).map_err(|e| e.to_string())
    }

    /// A 10×10 grid of points 0.5 apart in the plane y = 2 (a scanned floor).
    fn floor() -> Vec<DVec3> {
        (0..100)
            .map(|i| DVec3::new((i % 10) as f64 * 0.5, 2.0, (i / 10) as f64 * 0.5))
            .collect()
    }

    #[test]
    fn the_radius_is_half_the_nearest_neighbour_spacing_of_a_surface_or_a_volume() {
        assert_eq!(spacing_radius(&floor()), 0.25);
        let cube: Vec<DVec3> = (0..1000)
            .map(|i| DVec3::new((i % 10) as f64, (i / 10 % 10) as f64, (i / 100) as f64) * 3.0)
            .collect();
        assert_eq!(spacing_radius(&cube), 1.5);
        assert_eq!(spacing_radius(&[DVec3::ONE]), 0.5);
        assert_eq!(spacing_radius(&[DVec3::ONE; 3]), 0.5);
    }

    #[test]
    fn a_vertex_only_ply_loads_as_particles_not_a_refused_mesh() {
        let dir = tempfile::tempdir().unwrap();
        let mut text = String::from(
            "ply\nformat ascii 1.0\nelement vertex 100\nproperty float x\nproperty float y\n\
             property float z\nproperty uchar intensity\nelement face 0\n\
             property list uchar int vertex_indices\nend_header\n",
        );
        for (i, p) in floor().iter().enumerate() {
            text += &format!("{} {} {} {}\n", p.x, p.y, p.z, i % 7);
        }
        let scene = load_scene(dir.path(), "cloud.ply", text.as_bytes()).unwrap();
        assert_eq!(scene.particles.len(), 100);
        assert!(scene.triangles.is_empty());
        assert!(scene.particles.iter().all(|p| p.radius == 0.25));
        assert_eq!(
            scene.attribute_range(),
            (0.0, 6.0),
            "the intensity property"
        );

        // No face element at all, and no scalar property: the height is the attribute.
        let bare = text.replace("property uchar intensity\n", "").replace(
            "element face 0\nproperty list uchar int vertex_indices\n",
            "",
        );
        let bare: String = bare
            .lines()
            .map(|l| match l.split(' ').count() {
                4 => l.rsplit_once(' ').unwrap().0.to_string() + "\n",
                _ => l.to_string() + "\n",
            })
            .collect();
        let scene = load_scene(dir.path(), "bare.ply", bare.as_bytes()).unwrap();
        assert_eq!(scene.particles.len(), 100);
        assert_eq!(scene.attribute_range(), (2.0, 2.0));
    }

    #[test]
    fn an_xyz_only_csv_loads_as_particles_with_a_derived_radius() {
        let dir = tempfile::tempdir().unwrap();
        let mut text = String::from("X,y,z\n");
        for p in floor() {
            text += &format!("{},{},{}\n", p.x, p.y, p.z);
        }
        let scene = load_scene(dir.path(), "cloud.csv", text.as_bytes()).unwrap();
        assert_eq!(scene.particles.len(), 100);
        assert!(scene.particles.iter().all(|p| p.radius == 0.25));
        assert_eq!(scene.attribute_range(), (2.0, 2.0), "the height");
        // A radius column is still used as it is; an attribute column too.
        let text = "x,y,z,attribute\n0,0,0,5\n1,0,0,7\n";
        let scene = load_scene(dir.path(), "a.csv", text.as_bytes()).unwrap();
        assert_eq!(scene.attribute_range(), (5.0, 7.0));
        assert!(scene.particles.iter().all(|p| p.radius == 0.5));
    }

    #[test]
    fn bad_point_clouds_name_the_vertex() {
        let dir = tempfile::tempdir().unwrap();
        let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                    property float y\nproperty float z\nend_header\n";
        for (body, want) in [
            ("0 0 0\n1 1 1\n1 zz 0\n", "vertex 2 (line 10)"),
            (
                "0 0 0\n1 1e39 1\n1 0 0\n",
                "vertex 1 (line 9) has a non-finite coordinate",
            ),
            ("0 0 0\n", "vertex 1 (line 9)"),
        ] {
            let err = load_scene(dir.path(), "bad.ply", format!("{head}{body}").as_bytes());
            let err = err.unwrap_err();
            assert!(
                err.contains("bad.ply") && err.contains(want),
                "{want}: {err}"
            );
        }
        let no_z = head.replace("property float z\n", "");
        let err = load_scene(dir.path(), "noz.ply", no_z.as_bytes()).unwrap_err();
        assert!(
            err.contains("the `vertex` element has no `z` property"),
            "{err}"
        );
        let err = load_scene(dir.path(), "bad.csv", b"x,y,z\n1,2\n").unwrap_err();
        assert!(
            err.contains("line 2: 2 columns, but the header has 3"),
            "{err}"
        );
    }
}
