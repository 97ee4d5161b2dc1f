//! Procedural meshes for the object library (`datasets/objects/*.stl`).
//!
//! Every object is sized like the real straight edge of the MultiDiffSense example
//! (`../shared/real-sample/multidiffsense-example/stl/1.stl`): a 16 x 16 x 10 mm plinth with a
//! feature on top that rises to z = 20 mm, centred on the mesh origin. The feature is what the
//! sensor touches; the plinth keeps the objects printable and alike.
//!
//! The first five are the paper's training objects (straight edge, cuboid, sphere, Pacman,
//! hollow cylinder); `cross`, `cone` and `wedge` are novel ones. Meshes are triangle soups with
//! outward winding; overlapping parts (feature inside plinth) are fine for the z-buffer.

use std::f32::consts::TAU;

use glam::{Vec2, Vec3};

use super::stl::Mesh;

/// Plinth edge length, mm.
pub const PLINTH_SIDE_MM: f32 = 16.0;
/// Plinth height, mm (the feature starts here).
pub const PLINTH_HEIGHT_MM: f32 = 10.0;
/// Object top, mm.
pub const TOP_MM: f32 = 20.0;
/// Segments for round shapes: fine enough that facets stay below a pixel at 8.5 px/mm.
const ROUND_SEGMENTS: usize = 96;

/// Names of the library objects, in contact-sheet order.
pub const OBJECT_NAMES: &[&str] = &["edge", "cuboid", "sphere", "pacman", "hollow_cylinder", "cross", "cone", "wedge"];

/// The procedural mesh of a library object; `None` for an unknown name.
pub fn object_mesh(name: &str) -> Option<Mesh> {
    let feature = match name {
        // Straight edge: a 2 mm wide ridge across the whole plinth, as in the real object 1.
        "edge" => box_mesh(Vec3::new(-1.0, -8.0, PLINTH_HEIGHT_MM), Vec3::new(1.0, 8.0, TOP_MM)),
        "cuboid" => box_mesh(Vec3::new(-4.0, -4.0, PLINTH_HEIGHT_MM), Vec3::new(4.0, 4.0, TOP_MM)),
        // Sphere of radius 6 mm whose top is the object's top; its lower part hides in the plinth.
        "sphere" => sphere_mesh(Vec3::new(0.0, 0.0, TOP_MM - 6.0), 6.0, ROUND_SEGMENTS / 2, ROUND_SEGMENTS),
        "pacman" => extrude(&pacman_outline(6.0, 30.0), PLINTH_HEIGHT_MM, TOP_MM),
        "hollow_cylinder" => tube_mesh(6.0, 4.0, PLINTH_HEIGHT_MM, TOP_MM),
        "cross" => {
            let mut m = box_mesh(Vec3::new(-1.0, -7.0, PLINTH_HEIGHT_MM), Vec3::new(1.0, 7.0, TOP_MM));
            m.append(&box_mesh(Vec3::new(-7.0, -1.0, PLINTH_HEIGHT_MM), Vec3::new(7.0, 1.0, TOP_MM)));
            m
        }
        "cone" => cone_mesh(7.0, PLINTH_HEIGHT_MM, TOP_MM),
        // A knife edge: triangular cross-section 6 mm wide at the plinth, sharp at the top.
        "wedge" => {
            let section = [Vec2::new(-3.0, PLINTH_HEIGHT_MM), Vec2::new(3.0, PLINTH_HEIGHT_MM), Vec2::new(0.0, TOP_MM)];
            prism_along_y(&section, -8.0, 8.0)
        }
        _ => return None,
    };
    let h = PLINTH_SIDE_MM / 2.0;
    let mut mesh = box_mesh(Vec3::new(-h, -h, 0.0), Vec3::new(h, h, PLINTH_HEIGHT_MM));
    mesh.append(&feature);
    Some(mesh)
}

/// An axis-aligned box, 12 triangles.
pub fn box_mesh(min: Vec3, max: Vec3) -> Mesh {
    let outline = [Vec2::new(min.x, min.y), Vec2::new(max.x, min.y), Vec2::new(max.x, max.y), Vec2::new(min.x, max.y)];
    extrude(&outline, min.z, max.z)
}

/// Extrudes a counter-clockwise outline from `z0` to `z1`. The caps are fans from the first
/// vertex, so the outline must be star-shaped about it (convex outlines and the Pacman are).
pub fn extrude(outline: &[Vec2], z0: f32, z1: f32) -> Mesh {
    let mut t = Vec::new();
    let n = outline.len();
    let at = |p: Vec2, z: f32| Vec3::new(p.x, p.y, z);
    for i in 1..n.saturating_sub(1) {
        t.push([at(outline[0], z1), at(outline[i], z1), at(outline[i + 1], z1)]);
        t.push([at(outline[0], z0), at(outline[i + 1], z0), at(outline[i], z0)]);
    }
    for i in 0..n {
        let (a, b) = (outline[i], outline[(i + 1) % n]);
        t.push([at(a, z0), at(b, z0), at(b, z1)]);
        t.push([at(a, z0), at(b, z1), at(a, z1)]);
    }
    Mesh::new(t)
}

/// A prism whose cross-section (x, z), counter-clockwise seen from -y, runs from `y0` to `y1`.
pub fn prism_along_y(section_xz: &[Vec2], y0: f32, y1: f32) -> Mesh {
    // Extrude in a frame where the section lies in x-y, then swap y and z.
    let m = extrude(section_xz, y0, y1);
    Mesh::new(m.triangles.iter().map(|t| [t[0], t[2], t[1]].map(|v| Vec3::new(v.x, v.z, v.y))).collect())
}

/// Pacman outline: a disc of `radius_mm` with a mouth of `mouth_deg` (opening towards +x),
/// starting at the centre.
pub fn pacman_outline(radius_mm: f32, mouth_deg: f32) -> Vec<Vec2> {
    let half = (mouth_deg / 2.0).to_radians();
    let mut pts = vec![Vec2::ZERO];
    let steps = ROUND_SEGMENTS;
    for i in 0..=steps {
        let a = half + (TAU - 2.0 * half) * i as f32 / steps as f32;
        pts.push(Vec2::new(a.cos(), a.sin()) * radius_mm);
    }
    pts
}

/// A tube (hollow cylinder) from `z0` to `z1`.
pub fn tube_mesh(outer_mm: f32, inner_mm: f32, z0: f32, z1: f32) -> Mesh {
    let mut t = Vec::new();
    let n = ROUND_SEGMENTS;
    let p = |r: f32, i: usize, z: f32| {
        let a = TAU * (i % n) as f32 / n as f32;
        Vec3::new(r * a.cos(), r * a.sin(), z)
    };
    for i in 0..n {
        let j = i + 1;
        // Top and bottom rings.
        t.push([p(inner_mm, i, z1), p(outer_mm, i, z1), p(outer_mm, j, z1)]);
        t.push([p(inner_mm, i, z1), p(outer_mm, j, z1), p(inner_mm, j, z1)]);
        t.push([p(inner_mm, i, z0), p(outer_mm, j, z0), p(outer_mm, i, z0)]);
        t.push([p(inner_mm, i, z0), p(inner_mm, j, z0), p(outer_mm, j, z0)]);
        // Outer wall faces out, inner wall faces the hole.
        t.push([p(outer_mm, i, z0), p(outer_mm, j, z0), p(outer_mm, j, z1)]);
        t.push([p(outer_mm, i, z0), p(outer_mm, j, z1), p(outer_mm, i, z1)]);
        t.push([p(inner_mm, i, z0), p(inner_mm, j, z1), p(inner_mm, j, z0)]);
        t.push([p(inner_mm, i, z0), p(inner_mm, i, z1), p(inner_mm, j, z1)]);
    }
    Mesh::new(t)
}

/// A cone with its base disc at `z0` and apex at `z1`.
pub fn cone_mesh(radius_mm: f32, z0: f32, z1: f32) -> Mesh {
    let n = ROUND_SEGMENTS;
    let p = |i: usize| {
        let a = TAU * (i % n) as f32 / n as f32;
        Vec3::new(radius_mm * a.cos(), radius_mm * a.sin(), z0)
    };
    let apex = Vec3::new(0.0, 0.0, z1);
    let centre = Vec3::new(0.0, 0.0, z0);
    let mut t = Vec::new();
    for i in 0..n {
        t.push([p(i), p(i + 1), apex]);
        t.push([centre, p(i + 1), p(i)]);
    }
    Mesh::new(t)
}

/// A UV sphere with `rings` latitude bands and `segments` longitude segments.
pub fn sphere_mesh(centre: Vec3, radius_mm: f32, rings: usize, segments: usize) -> Mesh {
    let p = |ring: usize, seg: usize| {
        let theta = std::f32::consts::PI * ring as f32 / rings as f32;
        let phi = TAU * (seg % segments) as f32 / segments as f32;
        centre + radius_mm * Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
    };
    let mut t = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            let (a, b, c, d) = (p(r, s), p(r + 1, s), p(r + 1, s + 1), p(r, s + 1));
            if r != 0 {
                t.push([a, b, d]);
            }
            if r + 1 != rings {
                t.push([b, c, d]);
            }
        }
    }
    Mesh::new(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_object_has_the_real_objects_size() {
        for name in OBJECT_NAMES {
            let m = object_mesh(name).unwrap();
            let b = m.bounds();
            assert!((b.max.z - TOP_MM).abs() < 1e-4, "{name} top {}", b.max.z);
            assert!(b.min.z.abs() < 1e-4, "{name}");
            assert!((b.size().x - 16.0).abs() < 1e-4 && (b.size().y - 16.0).abs() < 1e-4, "{name} {:?}", b.size());
            assert!(m.triangles.iter().flatten().all(|v| v.is_finite()));
        }
        assert!(object_mesh("teapot").is_none());
    }

    #[test]
    fn extrude_winding_points_outwards() {
        // Signed volume of a closed, outward-wound mesh is positive and equals the box volume.
        let m = box_mesh(Vec3::ZERO, Vec3::new(2.0, 3.0, 4.0));
        let vol: f32 = m.triangles.iter().map(|t| t[0].dot(t[1].cross(t[2])) / 6.0).sum();
        assert!((vol - 24.0).abs() < 1e-3, "{vol}");
        let w = prism_along_y(&[Vec2::new(-1.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 1.0)], 0.0, 2.0);
        let vol: f32 = w.triangles.iter().map(|t| t[0].dot(t[1].cross(t[2])) / 6.0).sum();
        assert!((vol - 2.0).abs() < 1e-3, "{vol}");
    }
}
