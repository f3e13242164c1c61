//! Point-cloud file speed: `cargo bench -p handeye-calib --bench cloud_io`.
//!
//! Binary PLY read/write at full Zivid 2+ resolution (2448×2048, 5 M points) and at
//! 1280×960, binary PCD read, ASCII PLY/PCD read at 640×480, and voxel downsampling.
//! Files go to the system temp directory (page cache: this measures parsing, not the disk).
use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use handeye_calib::cloud::{read_cloud, voxel_downsample, write_pcd, write_ply, PlyEncoding};
use handeye_hal::nalgebra::Point3;
use handeye_hal::PointCloud;

/// An organized scan-like cloud: a wavy surface 0.5–0.8 m away, every 9th pixel invalid.
fn scan(width: u32, height: u32) -> PointCloud {
    let n = (width * height) as usize;
    let mut points = Vec::with_capacity(n);
    let mut intensity = Vec::with_capacity(n);
    let mut confidence = Vec::with_capacity(n);
    for v in 0..height {
        for u in 0..width {
            let i = (v * width + u) as usize;
            let z = 0.65 + 0.15 * ((u as f32) * 0.01).sin() * ((v as f32) * 0.013).cos();
            let x = (u as f32 - width as f32 / 2.0) / 2000.0 * z;
            let y = (v as f32 - height as f32 / 2.0) / 2000.0 * z;
            points.push(if i % 9 == 4 {
                Point3::new(f32::NAN, f32::NAN, f32::NAN)
            } else {
                Point3::new(x, y, z)
            });
            intensity.push((i % 251) as f32);
            confidence.push(((i % 97) as f32) / 97.0);
        }
    }
    PointCloud {
        width,
        height,
        points,
        intensity: Some(intensity),
        confidence: Some(confidence),
    }
}

fn tmp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("handeye-bench-{}-{name}", std::process::id()))
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("cloud_io");
    g.sample_size(10);
    for (w, h) in [(2448u32, 2048u32), (1280, 960)] {
        let cloud = scan(w, h);
        let xyz_only = PointCloud {
            intensity: None,
            confidence: None,
            ..cloud.clone()
        };
        g.throughput(Throughput::Elements(u64::from(w * h)));
        for (label, c) in [("xyz+i+c", &cloud), ("xyz", &xyz_only)] {
            let ply = tmp(&format!("{w}x{h}-{label}.ply"));
            g.bench_function(format!("write_ply_binary_{w}x{h}_{label}"), |b| {
                b.iter(|| {
                    write_ply(&ply, black_box(c), PlyEncoding::BinaryLittleEndian).expect("write")
                })
            });
            g.bench_function(format!("read_ply_binary_{w}x{h}_{label}"), |b| {
                b.iter(|| read_cloud(black_box(&ply)).expect("read"))
            });
            let pcd = tmp(&format!("{w}x{h}-{label}.pcd"));
            write_pcd(&pcd, c, true).expect("write");
            g.bench_function(format!("read_pcd_binary_{w}x{h}_{label}"), |b| {
                b.iter(|| read_cloud(black_box(&pcd)).expect("read"))
            });
            let _ = std::fs::remove_file(&ply);
            let _ = std::fs::remove_file(&pcd);
        }
    }
    let small = scan(640, 480);
    g.throughput(Throughput::Elements(640 * 480));
    let ply = tmp("640x480-ascii.ply");
    let pcd = tmp("640x480-ascii.pcd");
    g.bench_function("write_ply_ascii_640x480", |b| {
        b.iter(|| write_ply(&ply, black_box(&small), PlyEncoding::Ascii).expect("write"))
    });
    g.bench_function("read_ply_ascii_640x480", |b| {
        b.iter(|| read_cloud(black_box(&ply)).expect("read"))
    });
    write_pcd(&pcd, &small, false).expect("write");
    g.bench_function("read_pcd_ascii_640x480", |b| {
        b.iter(|| read_cloud(black_box(&pcd)).expect("read"))
    });
    let _ = std::fs::remove_file(&ply);
    let _ = std::fs::remove_file(&pcd);
    let big = scan(2448, 2048);
    g.throughput(Throughput::Elements(2448 * 2048));
    g.bench_function("voxel_downsample_2448x2048_2mm", |b| {
        b.iter(|| voxel_downsample(black_box(&big.points), 0.002))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
