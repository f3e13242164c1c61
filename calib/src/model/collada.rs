//! A small Collada (.dae) reader: triangle geometry and the visual-scene node hierarchy only.
//!
//! Written because `mesh-loader` 0.1.13 composes nested node transforms in the wrong order
//! (UR30 visual upper arm and forearm land up to 0.85 m off, UR20 visual wrist 2 loses a
//! 6.65 mm node translation). Here a node's transform is `parent · child`, each node's own
//! transform being the product of its `<matrix>`, `<translate>`, `<rotate>` and `<scale>`
//! elements in document order, as the Collada 1.4/1.5 specification says.
//!
//! Supported: `<triangles>`, `<polylist>`, `<polygons>`, `<trifans>`, `<tristrips>` (their
//! `VERTEX` input; other inputs only widen the index stride), `<instance_geometry>`,
//! `<instance_node>`, `<unit meter>` and `<up_axis>` (Y_UP and X_UP are turned to Z_UP).
//! Lines, materials, textures, skins and animations are ignored.

use std::collections::HashMap;

use handeye_hal::limits;
use nalgebra::{Matrix4, Point3, Rotation3, Unit, Vector3};
use roxmltree::{Document, Node, ParsingOptions};

use super::{TriMesh, MAX_MODEL_TRIANGLES};

/// Deepest node nesting (including `<instance_node>` hops) before we call it a cycle.
const MAX_DEPTH: usize = 64;

/// Most XML nodes (elements, text, …) in one document; a UR30 mesh has ~500.
const MAX_XML_NODES: u32 = 5_000_000;

/// Most scene nodes visited (`<instance_node>` can make a small file a huge tree).
const MAX_NODE_VISITS: usize = 1_000_000;

/// Parses a Collada document into one mesh in the document's root frame, converted to metres
/// and Z-up. Errors are human-readable reasons (the caller adds the path).
pub(crate) fn parse(bytes: &[u8]) -> Result<TriMesh, String> {
    let text = std::str::from_utf8(bytes).map_err(|e| format!("not UTF-8 text: {e}"))?;
    // roxmltree's tokenizer recurses per element: bound the nesting before it parses.
    limits::check_xml_nesting(text, limits::MAX_XML_DEPTH)?;
    let options = ParsingOptions {
        nodes_limit: MAX_XML_NODES,
        ..ParsingOptions::default()
    };
    let doc = Document::parse_with_options(text, options).map_err(|e| {
        format!(
            "not well-formed XML: {}",
            limits::sanitize_message(&e.to_string())
        )
    })?;
    let root = doc.root_element();
    if root.tag_name().name() != "COLLADA" {
        return Err(format!(
            "root element is <{}>, not <COLLADA>",
            root.tag_name().name()
        ));
    }
    let mut reader = Reader {
        visits: 0,
        ids: HashMap::new(),
        geometries: HashMap::new(),
        positions: HashMap::new(),
    };
    for n in root.descendants().filter(Node::is_element) {
        if let Some(id) = n.attribute("id") {
            reader.ids.entry(id).or_insert(n);
        }
    }

    let root_transform = root_transform(root)?;
    let mut out = TriMesh::default();
    match scene(root, &reader) {
        Some(scene) => {
            for node in children(scene, "node") {
                reader.visit(node, &root_transform, 0, &mut out)?;
            }
        }
        None => {
            // No scene: every geometry once, untransformed (what other loaders do).
            for g in root.descendants().filter(|n| n.has_tag_name("geometry")) {
                let mesh = reader.geometry(g)?;
                out.append_transformed(&mesh, &root_transform);
            }
        }
    }
    out.validate()?;
    Ok(out)
}

fn children<'a, 'i>(node: Node<'a, 'i>, name: &'static str) -> impl Iterator<Item = Node<'a, 'i>> {
    node.children()
        .filter(move |c| c.is_element() && c.tag_name().name() == name)
}

fn child<'a, 'i>(node: Node<'a, 'i>, name: &'static str) -> Option<Node<'a, 'i>> {
    children(node, name).next()
}

/// The visual scene to instance: the one `<scene>` names, else the first one.
fn scene<'a, 'i>(root: Node<'a, 'i>, reader: &Reader<'a, 'i>) -> Option<Node<'a, 'i>> {
    let named = child(root, "scene")
        .and_then(|s| child(s, "instance_visual_scene"))
        .and_then(|i| i.attribute("url"))
        .and_then(|u| reader.lookup(u));
    named.or_else(|| child(root, "library_visual_scenes").and_then(|l| child(l, "visual_scene")))
}

/// Unit scale and up-axis conversion from `<asset>`.
fn root_transform(root: Node<'_, '_>) -> Result<Matrix4<f64>, String> {
    let asset = child(root, "asset");
    let meter = match asset
        .and_then(|a| child(a, "unit"))
        .and_then(|u| u.attribute("meter"))
    {
        Some(m) => m
            .trim()
            .parse::<f64>()
            .map_err(|_| format!("bad <unit meter=\"{m}\">"))?,
        None => 1.0,
    };
    if !(meter.is_finite() && meter > 0.0) {
        return Err(format!("bad <unit meter=\"{meter}\">"));
    }
    let up = asset
        .and_then(|a| child(a, "up_axis"))
        .and_then(|u| u.text())
        .unwrap_or("Z_UP");
    let rotation = match up.trim() {
        "Z_UP" => Rotation3::identity(),
        // y → z: +90° about x.
        "Y_UP" => Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
        // x → z: −90° about y.
        "X_UP" => Rotation3::from_axis_angle(&Vector3::y_axis(), -std::f64::consts::FRAC_PI_2),
        other => return Err(format!("unknown <up_axis>{other}</up_axis>")),
    };
    Ok(rotation.to_homogeneous() * Matrix4::new_scaling(meter))
}

fn floats(node: Node<'_, '_>) -> Result<Vec<f64>, String> {
    node.text()
        .unwrap_or("")
        .split_ascii_whitespace()
        .map(|t| {
            t.parse::<f64>().map_err(|_| {
                format!(
                    "bad number `{}` in <{}>",
                    limits::Quoted(t),
                    node.tag_name().name()
                )
            })
        })
        .collect()
}

fn indices(node: Node<'_, '_>) -> Result<Vec<u32>, String> {
    node.text()
        .unwrap_or("")
        .split_ascii_whitespace()
        .map(|t| {
            t.parse::<u32>().map_err(|_| {
                format!(
                    "bad index `{}` in <{}>",
                    limits::Quoted(t),
                    node.tag_name().name()
                )
            })
        })
        .collect()
}

fn fixed<const N: usize>(node: Node<'_, '_>) -> Result<[f64; N], String> {
    let v = floats(node)?;
    v.try_into().map_err(|v: Vec<f64>| {
        format!(
            "<{}> has {} numbers, expected {N}",
            node.tag_name().name(),
            v.len()
        )
    })
}

struct Reader<'a, 'i> {
    /// Scene nodes visited so far (bounded by [`MAX_NODE_VISITS`]).
    visits: usize,
    ids: HashMap<&'a str, Node<'a, 'i>>,
    /// Parsed geometries by id.
    geometries: HashMap<&'a str, std::rc::Rc<TriMesh>>,
    /// Position arrays by `<vertices>` id.
    positions: HashMap<&'a str, std::rc::Rc<Vec<Point3<f64>>>>,
}

impl<'a, 'i> Reader<'a, 'i> {
    fn lookup(&self, url: &str) -> Option<Node<'a, 'i>> {
        self.ids.get(url.strip_prefix('#')?).copied()
    }

    fn visit(
        &mut self,
        node: Node<'a, 'i>,
        parent: &Matrix4<f64>,
        depth: usize,
        out: &mut TriMesh,
    ) -> Result<(), String> {
        if depth > MAX_DEPTH {
            return Err(format!(
                "node hierarchy deeper than {MAX_DEPTH} (an <instance_node> cycle?)"
            ));
        }
        self.visits += 1;
        if self.visits > MAX_NODE_VISITS {
            return Err(format!(
                "the scene instances more than {MAX_NODE_VISITS} nodes (<instance_node> repeated)"
            ));
        }
        let mut local = Matrix4::identity();
        for c in node.children().filter(Node::is_element) {
            local *= match c.tag_name().name() {
                "matrix" => Matrix4::from_row_slice(&fixed::<16>(c)?),
                "translate" => Matrix4::new_translation(&Vector3::from(fixed::<3>(c)?)),
                "scale" => Matrix4::new_nonuniform_scaling(&Vector3::from(fixed::<3>(c)?)),
                "rotate" => {
                    let [x, y, z, deg] = fixed::<4>(c)?;
                    match Unit::try_new(Vector3::new(x, y, z), 1e-12) {
                        Some(axis) => {
                            Rotation3::from_axis_angle(&axis, deg.to_radians()).to_homogeneous()
                        }
                        None => Matrix4::identity(),
                    }
                }
                "lookat" | "skew" => {
                    return Err(format!(
                        "<{}> node transforms are not supported",
                        c.tag_name().name()
                    ))
                }
                _ => continue,
            };
        }
        let world = parent * local;
        for c in node.children().filter(Node::is_element) {
            match c.tag_name().name() {
                "node" => self.visit(c, &world, depth + 1, out)?,
                "instance_node" => {
                    let url = c.attribute("url").unwrap_or("");
                    let target = self
                        .lookup(url)
                        .ok_or_else(|| format!("<instance_node url=\"{url}\"> names no node"))?;
                    self.visit(target, &world, depth + 1, out)?;
                }
                "instance_geometry" => {
                    let url = c.attribute("url").unwrap_or("");
                    let g = self
                        .lookup(url)
                        .filter(|g| g.has_tag_name("geometry"))
                        .ok_or_else(|| {
                            format!("<instance_geometry url=\"{url}\"> names no geometry")
                        })?;
                    let mesh = self.geometry(g)?;
                    if out.triangles.len() + mesh.triangles.len() > MAX_MODEL_TRIANGLES {
                        return Err(format!(
                            "the scene makes more than {MAX_MODEL_TRIANGLES} triangles"
                        ));
                    }
                    out.append_transformed(&mesh, &world);
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn geometry(&mut self, g: Node<'a, 'i>) -> Result<std::rc::Rc<TriMesh>, String> {
        let key = g.attribute("id");
        if let Some(m) = key.and_then(|k| self.geometries.get(k)) {
            return Ok(m.clone());
        }
        let mut out = TriMesh::default();
        // Output vertex offset of each <vertices> element already copied into `out`.
        let mut bases: HashMap<&'a str, (u32, u32)> = HashMap::new();
        if let Some(mesh) = child(g, "mesh") {
            for prim in mesh.children().filter(Node::is_element) {
                let kind = prim.tag_name().name();
                if !matches!(
                    kind,
                    "triangles" | "polylist" | "polygons" | "trifans" | "tristrips"
                ) {
                    continue;
                }
                let mut stride = 1usize;
                let mut vertex = None;
                for input in children(prim, "input") {
                    let offset: usize = input
                        .attribute("offset")
                        .unwrap_or("0")
                        .parse()
                        .map_err(|_| format!("bad <input offset> in <{kind}>"))?;
                    if offset > 64 {
                        return Err(format!("<input offset=\"{offset}\"> is implausibly large"));
                    }
                    stride = stride.max(offset + 1);
                    if input.attribute("semantic") == Some("VERTEX") {
                        vertex = Some((offset, input.attribute("source").unwrap_or("")));
                    }
                }
                let Some((offset, source)) = vertex else {
                    return Err(format!("<{kind}> has no VERTEX input"));
                };
                let vid = source.strip_prefix('#').unwrap_or(source);
                let (base, count) = match bases.get(vid) {
                    Some(&b) => b,
                    None => {
                        let positions = self.positions(source)?;
                        let base =
                            u32::try_from(out.vertices.len()).map_err(|_| "too many vertices")?;
                        let count =
                            u32::try_from(positions.len()).map_err(|_| "too many vertices")?;
                        out.vertices.extend(positions.iter().copied());
                        bases.insert(vid, (base, count));
                        (base, count)
                    }
                };
                let map = |i: u32| -> Result<u32, String> {
                    if i < count {
                        Ok(base + i)
                    } else {
                        Err(format!(
                            "vertex index {i} past the {count} positions of `{vid}`"
                        ))
                    }
                };
                let pick = |p: &[u32]| -> Result<Vec<u32>, String> {
                    p.iter()
                        .skip(offset)
                        .step_by(stride)
                        .map(|&i| map(i))
                        .collect()
                };
                match kind {
                    "triangles" => {
                        for p in children(prim, "p") {
                            let v = pick(&indices(p)?)?;
                            out.triangles
                                .extend(v.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
                        }
                    }
                    "polylist" => {
                        let counts = child(prim, "vcount")
                            .map(indices)
                            .transpose()?
                            .unwrap_or_default();
                        let v = match child(prim, "p") {
                            Some(p) => pick(&indices(p)?)?,
                            None => Vec::new(),
                        };
                        let mut at = 0usize;
                        for n in counts {
                            let n = n as usize;
                            let poly = v
                                .get(at..at.saturating_add(n))
                                .ok_or("<vcount> exceeds the indices in <p>")?;
                            fan(poly, &mut out.triangles);
                            at += n;
                        }
                    }
                    "polygons" | "trifans" => {
                        for p in prim.children().filter(Node::is_element) {
                            // <ph> holds an outer <p> plus holes <h>; holes are ignored.
                            let p = match p.tag_name().name() {
                                "p" => p,
                                "ph" => match child(p, "p") {
                                    Some(p) => p,
                                    None => continue,
                                },
                                _ => continue,
                            };
                            fan(&pick(&indices(p)?)?, &mut out.triangles);
                        }
                    }
                    _ => {
                        for p in children(prim, "p") {
                            let v = pick(&indices(p)?)?;
                            for (k, w) in v.windows(3).enumerate() {
                                out.triangles.push(if k % 2 == 0 {
                                    [w[0], w[1], w[2]]
                                } else {
                                    [w[1], w[0], w[2]]
                                });
                            }
                        }
                    }
                }
            }
        }
        let mesh = std::rc::Rc::new(out);
        if let Some(k) = key {
            self.geometries.insert(k, mesh.clone());
        }
        Ok(mesh)
    }

    /// Positions of a `<vertices>` element (its `POSITION` input's source).
    fn positions(&mut self, vertices_url: &str) -> Result<std::rc::Rc<Vec<Point3<f64>>>, String> {
        let vertices = self
            .lookup(vertices_url)
            .filter(|v| v.has_tag_name("vertices"))
            .ok_or_else(|| format!("VERTEX source `{vertices_url}` names no <vertices>"))?;
        let key = vertices.attribute("id").unwrap_or("");
        if let Some(p) = self.positions.get(key) {
            return Ok(p.clone());
        }
        let url = children(vertices, "input")
            .find(|i| i.attribute("semantic") == Some("POSITION"))
            .and_then(|i| i.attribute("source"))
            .ok_or_else(|| format!("<vertices id=\"{key}\"> has no POSITION input"))?;
        let source = self
            .lookup(url)
            .filter(|s| s.has_tag_name("source"))
            .ok_or_else(|| format!("POSITION source `{url}` names no <source>"))?;
        let array = child(source, "float_array")
            .ok_or_else(|| format!("<source> `{url}` has no <float_array>"))?;
        let values = floats(array)?;
        let accessor = child(source, "technique_common").and_then(|t| child(t, "accessor"));
        let attr = |name: &str, default: usize| -> Result<usize, String> {
            match accessor.and_then(|a| a.attribute(name)) {
                Some(v) => v
                    .trim()
                    .parse()
                    .map_err(|_| format!("bad <accessor {name}=\"{v}\">")),
                None => Ok(default),
            }
        };
        let stride = attr("stride", 3)?;
        let start = attr("offset", 0)?;
        if stride < 3 {
            return Err(format!(
                "position <accessor stride=\"{stride}\"> is below 3"
            ));
        }
        let available = values.len().saturating_sub(start) / stride;
        let count = attr("count", available)?.min(available);
        let points: Vec<Point3<f64>> = (0..count)
            .map(|i| {
                let k = start + i * stride;
                Point3::new(values[k], values[k + 1], values[k + 2])
            })
            .collect();
        let points = std::rc::Rc::new(points);
        self.positions.insert(key, points.clone());
        Ok(points)
    }
}

/// Triangulates a convex polygon as a fan around its first vertex.
fn fan(poly: &[u32], out: &mut Vec<[u32; 3]>) {
    if let Some((&first, rest)) = poly.split_first() {
        out.extend(rest.windows(2).map(|w| [first, w[0], w[1]]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc(up: &str, meter: &str, geometry: &str, scene: &str) -> String {
        format!(
            r##"<?xml version="1.0"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="u" meter="{meter}"/><up_axis>{up}</up_axis></asset>
  <library_geometries>{geometry}</library_geometries>
  <library_nodes><node id="lib"><translate>0 0 5</translate><instance_geometry url="#tri"/></node></library_nodes>
  <library_visual_scenes><visual_scene id="s">{scene}</visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>"##
        )
    }

    /// One triangle (1,0,0), (0,1,0), (0,0,1) as `<triangles>` with a NORMAL input at offset 1.
    const TRI: &str = r##"<geometry id="tri"><mesh>
      <source id="pos"><float_array id="pa" count="9">1 0 0 0 1 0 0 0 1</float_array>
        <technique_common><accessor source="#pa" count="3" stride="3"/></technique_common></source>
      <vertices id="v"><input semantic="POSITION" source="#pos"/></vertices>
      <triangles count="1"><input semantic="VERTEX" source="#v" offset="0"/>
        <input semantic="NORMAL" source="#n" offset="1"/><p>0 9 1 9 2 9</p></triangles>
    </mesh></geometry>"##;

    #[test]
    fn nested_transforms_compose_parent_then_child_in_document_order() {
        // Parent: translate x by 1 then rotate 90° about z. Child: translate y by 2.
        let scene = r##"<node><translate>1 0 0</translate><rotate>0 0 1 90</rotate>
            <node><translate>0 2 0</translate><instance_geometry url="#tri"/></node></node>"##;
        let m = parse(doc("Z_UP", "1", TRI, scene).as_bytes()).expect("parses");
        // p ↦ T(1,0,0)·Rz(90°)·T(0,2,0)·p; (1,0,0) → (1,2,0) → (-2,1,0) → (-1,1,0).
        let want = [
            Point3::new(-1.0, 1.0, 0.0),
            Point3::new(-2.0, 0.0, 0.0),
            Point3::new(-1.0, 0.0, 1.0),
        ];
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        for (v, w) in m.vertices.iter().zip(want) {
            assert!((v - w).norm() < 1e-12, "{v} vs {w}");
        }
    }

    #[test]
    fn matrix_is_row_major_and_instance_node_and_scale_apply() {
        let scene = r##"<node><matrix>1 0 0 10  0 1 0 0  0 0 1 0  0 0 0 1</matrix><scale>2 2 2</scale>
            <instance_node url="#lib"/></node>"##;
        let m = parse(doc("Z_UP", "0.001", TRI, scene).as_bytes()).expect("parses");
        // mm: ((1,0,0)+(0,0,5))·2 + (10,0,0) = (12, 0, 10) mm.
        assert!(
            (m.vertices[0] - Point3::new(0.012, 0.0, 0.010)).norm() < 1e-12,
            "{}",
            m.vertices[0]
        );
    }

    #[test]
    fn y_up_is_turned_to_z_up_and_polylist_is_fanned() {
        let poly = r##"<geometry id="tri"><mesh>
          <source id="pos"><float_array id="pa" count="12">0 0 0 1 0 0 1 1 0 0 1 0</float_array></source>
          <vertices id="v"><input semantic="POSITION" source="#pos"/></vertices>
          <polylist count="1"><input semantic="VERTEX" source="#v" offset="0"/><vcount>4</vcount><p>0 1 2 3</p></polylist>
        </mesh></geometry>"##;
        let m = parse(
            doc(
                "Y_UP",
                "1",
                poly,
                r##"<node><instance_geometry url="#tri"/></node>"##,
            )
            .as_bytes(),
        )
        .expect("parses");
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        // (1,1,0) Y-up → (1,0,1) Z-up.
        assert!(
            (m.vertices[2] - Point3::new(1.0, 0.0, 1.0)).norm() < 1e-12,
            "{}",
            m.vertices[2]
        );
    }

    #[test]
    fn bad_documents_are_errors() {
        let scene = r##"<node><instance_geometry url="#tri"/></node>"##;
        let out_of_range = TRI.replace("<p>0 9 1 9 2 9</p>", "<p>0 9 1 9 7 9</p>");
        assert!(parse(doc("Z_UP", "1", &out_of_range, scene).as_bytes()).is_err());
        let cycle = r##"<node id="a"><instance_node url="#a"/></node>"##;
        assert!(parse(doc("Z_UP", "1", TRI, cycle).as_bytes())
            .expect_err("must fail")
            .contains("deeper"));
        assert!(parse(b"<html/>").is_err());
        assert!(parse(&[0xff, 0xfe, 0x00]).is_err());
        assert!(parse(doc("Z_UP", "nan", TRI, scene).as_bytes()).is_err());
    }
}
