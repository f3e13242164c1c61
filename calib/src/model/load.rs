//! Loading a robot model: the URDF read and checked, its meshes and primitives built in their
//! links' frames ([`RobotModel::load`]).

use super::*;

fn pose_to_isometry(p: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = p.xyz.0;
    let [r, pi, yaw] = p.rpy.0;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(r, pi, yaw),
    )
}

fn pose_is_finite(p: &urdf_rs::Pose) -> bool {
    p.xyz.0.iter().chain(p.rpy.0.iter()).all(|v| v.is_finite())
}

/// Tessellates a primitive from its dimensions.
type Tessellate = fn(&[f64]) -> TriMesh;

/// One geometry element to build: which link, which kind, and what.
struct Element<'r> {
    link: usize,
    kind: GeometryKind,
    origin: &'r urdf_rs::Pose,
    geometry: &'r urdf_rs::Geometry,
}

/// Every `*.urdf` file below `dir` (recursively), sorted; unreadable folders are skipped.
pub fn find_urdfs(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for p in entries.flatten().map(|e| e.path()) {
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "urdf") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

impl RobotModel {
    /// Loads a URDF and all its meshes (visual and collision).
    pub fn load(urdf_path: &Path) -> Result<Self, ModelError> {
        let read_error = |source| ModelError::ReadUrdf {
            path: urdf_path.to_path_buf(),
            source,
        };
        let text = limits::read_text_file(urdf_path, MAX_URDF_BYTES).map_err(read_error)?;
        let malformed = |reason: String| ModelError::MalformedUrdf {
            path: urdf_path.to_path_buf(),
            reason,
        };
        // urdf-rs parses and re-serializes recursively: bound the nesting before it sees it.
        limits::check_xml_nesting(&text, limits::MAX_XML_DEPTH).map_err(malformed)?;
        let robot = urdf_rs::read_from_string(&text)
            .map_err(|e| malformed(limits::sanitize_message(&e.to_string())))?;
        let mut model = Self::from_urdf(&robot, urdf_path).map_err(malformed)?;
        let base_dir = urdf_path.parent().unwrap_or(Path::new("."));
        model.load_geometry(&robot, base_dir)?;
        Ok(model)
    }

    /// Builds the kinematic tree (no meshes). Errors are reasons for `MalformedUrdf`.
    fn from_urdf(robot: &urdf_rs::Robot, urdf_path: &Path) -> Result<Self, String> {
        let link_names: Vec<String> = robot.links.iter().map(|l| l.name.clone()).collect();
        if link_names.is_empty() {
            return Err("it has no <link>".into());
        }
        let mut link_index = HashMap::new();
        for (i, n) in link_names.iter().enumerate() {
            if link_index.insert(n.clone(), i).is_some() {
                return Err(format!("link `{n}` is defined twice"));
            }
        }
        let find = |name: &str, joint: &str| {
            link_index
                .get(name)
                .copied()
                .ok_or_else(|| format!("joint `{joint}` names unknown link `{name}`"))
        };
        // Parent joint of each link.
        let mut parent_joint: Vec<Option<usize>> = vec![None; link_names.len()];
        let mut kids: Vec<Vec<usize>> = vec![Vec::new(); link_names.len()];
        for (j, joint) in robot.joints.iter().enumerate() {
            let p = find(&joint.parent.link, &joint.name)?;
            let c = find(&joint.child.link, &joint.name)?;
            if parent_joint[c].replace(j).is_some() {
                return Err(format!(
                    "link `{}` is the child of two joints",
                    joint.child.link
                ));
            }
            kids[p].push(c);
            if !pose_is_finite(&joint.origin) {
                return Err(format!("joint `{}` has a non-finite <origin>", joint.name));
            }
            let [x, y, z] = joint.origin.xyz.0;
            if Vector3::new(x, y, z).norm() > MAX_LINK_EXTENT_M {
                return Err(format!(
                    "joint `{}` has its <origin> {:.3e} m from its parent link (at most {MAX_LINK_EXTENT_M} m; lengths are in metres)",
                    joint.name,
                    Vector3::new(x, y, z).norm()
                ));
            }
        }
        let roots: Vec<usize> = (0..link_names.len())
            .filter(|&i| parent_joint[i].is_none())
            .collect();
        let root = match roots.as_slice() {
            [r] => *r,
            [] => return Err("no root link (the joints form a cycle)".into()),
            _ => {
                let names: Vec<&str> = roots.iter().map(|&r| link_names[r].as_str()).collect();
                return Err(format!(
                    "several root links ({}); join them with fixed joints",
                    names.join(", ")
                ));
            }
        };
        // Breadth-first order from the root; links not reached sit on a cycle.
        let mut order = Vec::with_capacity(link_names.len());
        let mut queue = VecDeque::from([root]);
        while let Some(l) = queue.pop_front() {
            order.push(l);
            queue.extend(kids[l].iter().copied());
        }
        if order.len() != link_names.len() {
            return Err("some links are not connected to the root (a cycle of joints)".into());
        }

        let is_movable = |l: usize| {
            parent_joint[l].is_some_and(|j| {
                matches!(
                    robot.joints[j].joint_type,
                    urdf_rs::JointType::Revolute
                        | urdf_rs::JointType::Continuous
                        | urdf_rs::JointType::Prismatic
                )
            })
        };
        // Movable and total joints from the root, to pick the chain tip.
        let mut movable_depth = vec![0usize; link_names.len()];
        let mut depth = vec![0usize; link_names.len()];
        for &l in &order {
            for &c in &kids[l] {
                movable_depth[c] = movable_depth[l] + usize::from(is_movable(c));
                depth[c] = depth[l] + 1;
            }
        }
        let flange = ["tool0", "flange"]
            .iter()
            .find_map(|n| link_index.get(*n).copied())
            .unwrap_or_else(|| {
                // The first link (document order) with the most movable joints, then the most joints.
                let mut best = root;
                for l in 0..link_names.len() {
                    if (movable_depth[l], depth[l]) > (movable_depth[best], depth[best]) {
                        best = l;
                    }
                }
                best
            });
        // Chain joints: movable joints on the path root → flange.
        let mut chain_links = Vec::new();
        let mut l = flange;
        while let Some(j) = parent_joint[l] {
            if is_movable(l) {
                chain_links.push(l);
            }
            l = link_index[&robot.joints[j].parent.link];
        }
        chain_links.reverse();
        let chain_slot: HashMap<usize, usize> = chain_links
            .iter()
            .enumerate()
            .map(|(i, &l)| (l, i))
            .collect();
        let joint_slot: HashMap<&str, usize> = chain_links
            .iter()
            .enumerate()
            .filter_map(|(i, &l)| parent_joint[l].map(|j| (robot.joints[j].name.as_str(), i)))
            .collect();

        let mut joint_names = Vec::new();
        let mut joint_limits = Vec::new();
        let mut continuous = Vec::new();
        for &l in &chain_links {
            let Some(j) = parent_joint[l] else { continue };
            let joint = &robot.joints[j];
            let lim = &joint.limit;
            let (lower, upper) = if joint.joint_type == urdf_rs::JointType::Continuous {
                (-TAU, TAU)
            } else {
                (lim.lower, lim.upper)
            };
            if lower.is_nan() || upper.is_nan() || lower > upper {
                return Err(format!(
                    "joint `{}` has limits lower {lower} > upper {upper}",
                    joint.name
                ));
            }
            if lower.abs() > MAX_JOINT_LIMIT || upper.abs() > MAX_JOINT_LIMIT {
                return Err(format!(
                    "joint `{}` has limits [{lower:e}, {upper:e}]: expected within ±{MAX_JOINT_LIMIT} (radians, metres for prismatic joints; use type=\"continuous\" for an unlimited joint)",
                    joint.name
                ));
            }
            joint_names.push(joint.name.clone());
            continuous.push(joint.joint_type == urdf_rs::JointType::Continuous);
            joint_limits.push(JointLimit {
                lower,
                upper,
                velocity: lim.velocity,
            });
        }

        let mut links = Vec::with_capacity(link_names.len());
        for (l, &parent) in parent_joint.iter().enumerate() {
            let Some(j) = parent else {
                links.push(LinkNode {
                    parent: None,
                    parent_from_joint: Isometry3::identity(),
                    motion: Motion::Fixed,
                    chain_depth: 0,
                });
                continue;
            };
            let joint = &robot.joints[j];
            let q = match (chain_slot.get(&l), &joint.mimic) {
                (Some(&i), _) => QSource::Chain(i),
                (None, Some(m)) => match joint_slot.get(m.joint.as_str()) {
                    Some(&index) => {
                        let (multiplier, offset) =
                            (m.multiplier.unwrap_or(1.0), m.offset.unwrap_or(0.0));
                        if !(multiplier.abs() <= MAX_JOINT_LIMIT && offset.abs() <= MAX_JOINT_LIMIT)
                        {
                            return Err(format!(
                                "joint `{}` has <mimic multiplier=\"{multiplier}\" offset=\"{offset}\">: expected finite values within ±{MAX_JOINT_LIMIT}",
                                joint.name
                            ));
                        }
                        QSource::Mimic {
                            index,
                            multiplier,
                            offset,
                        }
                    }
                    None => QSource::Zero,
                },
                (None, None) => QSource::Zero,
            };
            let axis = || {
                let v = Vector3::from(joint.axis.xyz.0);
                Unit::try_new(v, 1e-9)
                    .filter(|a| a.iter().all(|c| c.is_finite()))
                    .ok_or_else(|| {
                        format!("joint `{}` has an invalid <axis xyz=\"{v:?}\">", joint.name)
                    })
            };
            let motion = match joint.joint_type {
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                    Motion::Revolute { axis: axis()?, q }
                }
                urdf_rs::JointType::Prismatic => Motion::Prismatic { axis: axis()?, q },
                // Floating, planar and spherical joints are held at their zero position.
                _ => Motion::Fixed,
            };
            links.push(LinkNode {
                parent: Some(link_index[&joint.parent.link]),
                parent_from_joint: pose_to_isometry(&joint.origin),
                motion,
                chain_depth: 0,
            });
        }
        for &l in &order {
            if let Some(p) = links[l].parent {
                links[l].chain_depth =
                    links[p].chain_depth + usize::from(chain_slot.contains_key(&l));
            }
        }

        Ok(RobotModel {
            name: robot.name.clone(),
            urdf_path: urdf_path.to_path_buf(),
            link_names,
            link_index,
            links,
            order,
            root,
            flange,
            joint_names,
            joint_limits,
            continuous,
            visual: Vec::new(),
            collision: Vec::new(),
        })
    }

    fn load_geometry(&mut self, robot: &urdf_rs::Robot, base_dir: &Path) -> Result<(), ModelError> {
        let mut elements = Vec::new();
        for (l, link) in robot.links.iter().enumerate() {
            for v in &link.visual {
                elements.push(Element {
                    link: l,
                    kind: GeometryKind::Visual,
                    origin: &v.origin,
                    geometry: &v.geometry,
                });
            }
            for c in &link.collision {
                elements.push(Element {
                    link: l,
                    kind: GeometryKind::Collision,
                    origin: &c.origin,
                    geometry: &c.geometry,
                });
            }
        }
        // Each distinct mesh file once, in parallel.
        let mut files: Vec<(PathBuf, usize)> = Vec::new();
        for e in &elements {
            if let urdf_rs::Geometry::Mesh { filename, .. } = e.geometry {
                let path = resolve_mesh_path(filename, base_dir, &self.link_names[e.link])?;
                if !files.iter().any(|(p, _)| *p == path) {
                    files.push((path, e.link));
                }
            }
        }
        let meshes: HashMap<PathBuf, TriMesh> = files
            .par_iter()
            .map(|(path, link)| Ok((path.clone(), read_mesh(path, &self.link_names[*link])?)))
            .collect::<Result<_, ModelError>>()?;

        let mut merged: HashMap<(usize, GeometryKind), TriMesh> = HashMap::new();
        for e in &elements {
            let link = &self.link_names[e.link];
            let bad = |reason: String| ModelError::MalformedUrdf {
                path: self.urdf_path.clone(),
                reason,
            };
            if !pose_is_finite(e.origin) {
                return Err(bad(format!(
                    "a geometry <origin> of link `{link}` is not finite"
                )));
            }
            let link_from_geometry = pose_to_isometry(e.origin).to_homogeneous();
            let out = merged.entry((e.link, e.kind)).or_default();
            match e.geometry {
                urdf_rs::Geometry::Mesh { filename, scale } => {
                    let path = resolve_mesh_path(filename, base_dir, link)?;
                    let s = scale.as_ref().map_or([1.0; 3], |s| s.0);
                    if !s.iter().all(|v| v.is_finite() && *v != 0.0) {
                        return Err(bad(format!(
                            "mesh scale {s:?} of link `{link}` is not finite and non-zero"
                        )));
                    }
                    let m = link_from_geometry * Matrix4::new_nonuniform_scaling(&Vector3::from(s));
                    if let Some(mesh) = meshes.get(&path) {
                        if out.triangles.len() + mesh.triangles.len() > MAX_MODEL_TRIANGLES {
                            return Err(bad(format!(
                                "link `{link}` has more than {MAX_MODEL_TRIANGLES} triangles"
                            )));
                        }
                        out.append_transformed(mesh, &m);
                    }
                }
                primitive => {
                    let (dims, mesh): (Vec<f64>, Tessellate) = match primitive {
                        urdf_rs::Geometry::Box { size } => {
                            (size.0.to_vec(), |d| primitives::cuboid([d[0], d[1], d[2]]))
                        }
                        urdf_rs::Geometry::Cylinder { radius, length } => {
                            (vec![*radius, *length], |d| primitives::cylinder(d[0], d[1]))
                        }
                        urdf_rs::Geometry::Capsule { radius, length } => {
                            (vec![*radius, *length], |d| primitives::capsule(d[0], d[1]))
                        }
                        urdf_rs::Geometry::Sphere { radius } => {
                            (vec![*radius], |d| primitives::sphere(d[0]))
                        }
                        urdf_rs::Geometry::Mesh { .. } => continue,
                    };
                    if !dims.iter().all(|v| v.is_finite() && *v >= 0.0) {
                        return Err(bad(format!("geometry {primitive:?} of link `{link}` has a negative or non-finite size")));
                    }
                    if dims.iter().any(|v| *v > MAX_LINK_EXTENT_M) {
                        return Err(bad(format!(
                            "geometry {primitive:?} of link `{link}` is larger than {MAX_LINK_EXTENT_M} m; sizes are in metres"
                        )));
                    }
                    // Zero-size placeholders (`<box size="0 0 0">`, as in the Elite URDFs) add nothing.
                    if dims.iter().all(|v| *v > 0.0)
                        || matches!(primitive, urdf_rs::Geometry::Capsule { .. } if dims[0] > 0.0)
                    {
                        out.append_transformed(&mesh(&dims), &link_from_geometry);
                    }
                }
            }
        }
        for ((l, _), mesh) in &merged {
            let outside = mesh.vertices.iter().any(|v| {
                v.coords
                    .iter()
                    .any(|c| !c.is_finite() || c.abs() > MAX_LINK_EXTENT_M)
            });
            if outside {
                return Err(ModelError::MalformedUrdf {
                    path: self.urdf_path.clone(),
                    reason: format!(
                        "the geometry of link `{}` reaches farther than {MAX_LINK_EXTENT_M} m from the link's origin \
                         (a <mesh scale> or <origin> in the wrong unit?); lengths are in metres",
                        self.link_names[*l]
                    ),
                });
            }
        }
        for l in 0..self.link_names.len() {
            for (kind, list) in [
                (GeometryKind::Visual, &mut self.visual),
                (GeometryKind::Collision, &mut self.collision),
            ] {
                if let Some(mesh) = merged.remove(&(l, kind)).filter(|m| !m.is_empty()) {
                    list.push(LinkGeometry {
                        link: self.link_names[l].clone(),
                        mesh: Arc::new(mesh),
                    });
                }
            }
        }
        Ok(())
    }
}

/// Resolves a URDF mesh filename: relative to the URDF directory, absolute, or `file://`.
fn resolve_mesh_path(filename: &str, base_dir: &Path, link: &str) -> Result<PathBuf, ModelError> {
    let path = filename.strip_prefix("file://").unwrap_or(filename);
    if path.contains("://") {
        return Err(ModelError::UnsupportedMeshUri {
            link: link.to_string(),
            uri: filename.to_string(),
        });
    }
    let path = Path::new(path);
    Ok(if path.is_absolute() {
        path.to_path_buf()
    } else {
        base_dir.join(path)
    })
}

/// Reads one mesh file in its own coordinates (no URDF origin or scale yet).
pub(super) fn read_mesh(path: &Path, link: &str) -> Result<TriMesh, ModelError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if !matches!(ext.as_str(), "stl" | "obj" | "dae") {
        return Err(ModelError::UnsupportedMeshFormat {
            link: link.to_string(),
            path: path.to_path_buf(),
        });
    }
    let unreadable = |e: std::io::Error| ModelError::MissingMesh {
        link: link.to_string(),
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    limits::check_regular_file(path, MAX_MESH_FILE_BYTES).map_err(unreadable)?;
    let bytes = std::fs::read(path).map_err(unreadable)?;
    parse_mesh(&bytes, &ext, path, link)
}

/// Parses the bytes of a mesh file of extension `ext` (`stl`, `obj` or `dae`, lower case);
/// `path` and `link` name it in errors.
pub(super) fn parse_mesh(
    bytes: &[u8],
    ext: &str,
    path: &Path,
    link: &str,
) -> Result<TriMesh, ModelError> {
    let malformed = |reason: String| ModelError::MalformedMesh {
        link: link.to_string(),
        path: path.to_path_buf(),
        reason,
    };
    let mesh = match ext {
        "dae" => collada::parse(bytes).map_err(malformed)?,
        "stl" if !stl_size_matches(bytes) => {
            return Err(malformed(stl_size_mismatch(bytes)));
        }
        _ => {
            let loader = mesh_loader::Loader::default();
            let scene = if ext == "stl" {
                loader.load_stl_from_slice(bytes, path)
            } else {
                // Materials are not needed: never read the .mtl files.
                loader.load_obj_from_slice_with_reader(bytes, path, |_| Ok(Vec::new()))
            }
            .map_err(|e| malformed(limits::sanitize_message(&e.to_string())))?;
            from_scene(&scene).map_err(malformed)?
        }
    };
    // A link whose mesh reads as nothing would silently leave the model without it (the scan
    // would then be fitted, and paths checked, without that link).
    if mesh.triangles.is_empty() {
        return Err(malformed(
            "it holds no triangles (an empty or truncated file; an STL whose header claims more \
             triangles than the file holds reads as none)"
                .into(),
        ));
    }
    if let Some(v) = mesh
        .vertices
        .iter()
        .find(|v| !v.coords.iter().all(|c| c.is_finite()))
    {
        return Err(malformed(format!("a vertex is not finite ({v:?})")));
    }
    Ok(mesh)
}

/// Whether an STL file is either a binary STL exactly as long as its header's triangle count
/// says (84 + 50 bytes per triangle), or ASCII (`solid …`, text only). A binary STL may also
/// begin with `solid` (some CAD tools write it), so the length decides first, and a file
/// with bytes no text holds (a binary count, floats) is binary.
fn stl_size_matches(bytes: &[u8]) -> bool {
    match stl_claimed_bytes(bytes) {
        Some(claimed) if claimed == bytes.len() as u64 => true,
        _ => {
            bytes.trim_ascii_start().starts_with(b"solid")
                && bytes
                    .iter()
                    .all(|b| b.is_ascii_graphic() || b.is_ascii_whitespace())
        }
    }
}

/// The length a binary STL's header claims (84 + 50 × its triangle count), if it has one.
fn stl_claimed_bytes(bytes: &[u8]) -> Option<u64> {
    let count = bytes.get(80..84)?;
    let count = u32::from_le_bytes(count.try_into().ok()?);
    Some(84 + 50 * u64::from(count))
}

/// Why an STL that is neither ASCII nor as long as its binary header says was refused.
fn stl_size_mismatch(bytes: &[u8]) -> String {
    match stl_claimed_bytes(bytes) {
        Some(claimed) => format!(
            "its binary header claims {} triangles ({claimed} bytes) but the file holds {} \
             bytes: a truncated or corrupt file",
            (claimed - 84) / 50,
            bytes.len()
        ),
        None => format!(
            "{} bytes are neither an ASCII STL (`solid …`) nor a binary STL's 84-byte header",
            bytes.len()
        ),
    }
}

/// Flattens a mesh-loader scene (STL, OBJ) into one [`TriMesh`].
pub(super) fn from_scene(scene: &mesh_loader::Scene) -> Result<TriMesh, String> {
    let mut out = TriMesh::default();
    for m in &scene.meshes {
        if out.triangles.len() + m.faces.len() > MAX_MODEL_TRIANGLES {
            return Err(format!("more than {MAX_MODEL_TRIANGLES} triangles"));
        }
        let base = u32::try_from(out.vertices.len()).map_err(|_| "too many vertices")?;
        out.vertices.extend(
            m.vertices
                .iter()
                .map(|v| nalgebra::Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))),
        );
        out.triangles
            .extend(m.faces.iter().map(|f| f.map(|i| base.saturating_add(i))));
    }
    out.validate()?;
    Ok(out)
}
