//! The `eprop` command line.

use anyhow::{bail, Result};
use clap::{Parser, Subcommand, ValueEnum};
use eprop::run::{mesh_info, run, RunOptions};
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "eprop",
    version,
    about = "Soft-tissue deformation by Poisson energy propagation",
    long_about = "eprop turns a force on an organ into a directional energy source, spreads that energy \
through the volume with a vector Poisson equation (median-dual finite volumes, explicit Euler) \
and moves the nodes with damped dynamics driven by the propagated potential.\n\n\
A run is described by a scenario file (TOML): mesh, material, model, fixed set, loads, time, output.\n\
Results go to one HDF5 file (VTKHDF) that ParaView opens and h5py reads.",
    after_help = "Examples:\n  eprop mesh cylinder -o cyl.msh\n  eprop info cyl.msh\n  eprop run scenarios/cylinder.toml\n  mpirun -n 2 eprop run scenarios/cylinder.toml --output out.h5"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run a scenario to its stop condition and write the HDF5 series.
    #[command(long_about = "Run a scenario to its stop condition and write the HDF5 series.\n\n\
Scenario keys (all but [mesh] file and [time] have defaults):\n\
  [mesh]      file = \"organ.msh\"             (relative to the scenario file)\n\
  [material]  mass = 1.0, damping = 2.0, conductivity = 0.05 | [rx, ry, rz] | 3x3 table\n\
  [[material.region]]  box | sphere | halfspace | tag | group, and conductivity / mass / damping\n\
  [model]     scheme = \"compact\" | \"paper\", paper_correction = true,\n\
              stiffness = 1.0 (k_e), coupling = 1.0 (kappa), exponent = 1.0 (p)\n\
  [tissue]    young = 100.0, beta = 0.0 (exponential law when > 0)\n\
  [[fixed]]   box = [[x0,y0,z0],[x1,y1,z1]] | sphere = {center, radius} |\n\
              halfspace = {point, normal} | nodes = [ids] | tag = N | group = \"name\"\n\
  [[load]]    node = ID | nearest = [x,y,z];  force = [fx,fy,fz] | normal = magnitude;\n\
              ramp = [[t0, s0], [t1, s1], ...] (optional scale in time)\n\
  [time]      steps = N | end = T | equilibrium = tol;  dt, h optional (automatic)\n\
  [output]    file = \"out.h5\", every = 1\n\n\
The summary gives the substep h, the steps, the speed, the largest displacement and the\n\
contact displacement of each load. Run under mpirun for several processes.")]
    Run {
        /// Scenario file (TOML)
        scenario: PathBuf,
        /// Output file (overrides [output] file)
        #[arg(long, short)]
        output: Option<PathBuf>,
        /// Number of steps (overrides [time])
        #[arg(long)]
        steps: Option<u64>,
        /// Print the summary as JSON
        #[arg(long)]
        json: bool,
        /// No progress lines
        #[arg(long, short)]
        quiet: bool,
    },
    /// Describe a mesh: counts, volume, control-volume checks, quality, stable substep.
    Info {
        /// Mesh file (.msh, .vtk, .vtu, .node/.ele, .mesh)
        mesh: PathBuf,
        /// Print JSON
        #[arg(long)]
        json: bool,
        /// Refuse inverted cells instead of reorienting them
        #[arg(long)]
        strict: bool,
    },
    /// Convert a mesh: read any supported format, validate, write .msh (Gmsh 4.1) or .vtu.
    Convert {
        /// Input mesh (.msh, .vtk, .vtu, .node/.ele, .mesh)
        input: PathBuf,
        /// Output mesh (.msh or .vtu)
        output: PathBuf,
        /// Refuse inverted cells instead of reorienting them
        #[arg(long)]
        strict: bool,
    },
    /// Generate a mesh: the paper's cylinder or a box.
    Mesh {
        #[command(subcommand)]
        shape: Shape,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum Kind {
    Tet,
    Hex,
    Prism,
}

#[derive(Subcommand)]
enum Shape {
    /// A cylinder along z (defaults: the paper-sized cylinder, 444 nodes / 1782 tetrahedra).
    /// Faces are tagged bottom (z = 0), top, side.
    Cylinder {
        #[arg(long, default_value_t = 1.0)]
        radius: f64,
        #[arg(long, default_value_t = 4.0)]
        length: f64,
        /// Rings of nodes around the axis (ring k holds 6k nodes)
        #[arg(long, default_value_t = 3)]
        rings: usize,
        /// Cell layers along the axis
        #[arg(long, default_value_t = 11)]
        layers: usize,
        /// Output file (.msh, Gmsh 4.1)
        #[arg(short, long)]
        output: PathBuf,
    },
    /// A box [0,X]x[0,Y]x[0,Z]; faces are tagged xmin, xmax, ymin, ymax, zmin, zmax.
    Box {
        /// Size X,Y,Z
        #[arg(long, value_delimiter = ',', default_values_t = [1.0, 1.0, 1.0])]
        size: Vec<f64>,
        /// Cells along each axis NX,NY,NZ
        #[arg(long, value_delimiter = ',', default_values_t = [10, 10, 10])]
        cells: Vec<usize>,
        /// Cell kind
        #[arg(long, value_enum, default_value_t = Kind::Tet)]
        kind: Kind,
        /// Output file (.msh, Gmsh 4.1)
        #[arg(short, long)]
        output: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match real_main(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// True when started by an MPI launcher.
fn under_mpirun() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS"]
        .iter()
        .any(|v| std::env::var_os(v).is_some())
}

/// Runs under MPI; an error on any process prints its message and ends every process with a
/// non-zero exit (MPI_Abort), so a batch job never hangs on a failed rank.
fn run_under_mpi(scenario: &std::path::Path, opts: &RunOptions) -> Option<eprop::run::Summary> {
    use mpi::topology::Communicator;
    let Some(universe) = mpi::initialize() else {
        eprintln!("error: MPI could not be initialised");
        std::process::exit(1);
    };
    let world = universe.world();
    let (rank, size) = (world.rank(), world.size());
    let abort_world = universe.world();
    match eprop::run::run_mpi(world, scenario, opts) {
        Ok(s) => s,
        Err(e) => {
            if size > 1 {
                eprintln!("error (rank {rank} of {size}): {e:#}");
            } else {
                eprintln!("error: {e:#}");
            }
            abort_world.abort(1)
        }
    }
}

fn real_main(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Run {
            scenario,
            output,
            steps,
            json,
            quiet,
        } => {
            let opts = RunOptions {
                output,
                steps,
                quiet: quiet || json,
            };
            let summary = if under_mpirun() {
                run_under_mpi(&scenario, &opts)
            } else {
                Some(run(&scenario, &opts)?)
            };
            if let Some(s) = summary {
                if json {
                    println!("{}", serde_json::to_string_pretty(&s)?);
                } else {
                    println!("{s}");
                }
            }
        }
        Cmd::Convert { input, output, strict } => {
            let m = eprop_io::read_mesh_with(&input, &eprop_io::ReadOptions { strict })?;
            for w in &m.warnings {
                eprintln!("warning: {w}");
            }
            eprop_io::write_mesh(&m, &output)?;
            println!("{}: {} nodes, {} cells", output.display(), m.n_nodes(), m.n_cells());
        }
        Cmd::Info { mesh, json, strict } => {
            let m = eprop_io::read_mesh_with(&mesh, &eprop_io::ReadOptions { strict })?;
            let info = mesh_info(&m);
            if json {
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                println!("{info}");
            }
        }
        Cmd::Mesh { shape } => {
            let (mesh, out) = match shape {
                Shape::Cylinder {
                    radius,
                    length,
                    rings,
                    layers,
                    output,
                } => (cylinder_mesh(radius, length, rings, layers)?, output),
                Shape::Box {
                    size,
                    cells,
                    kind,
                    output,
                } => {
                    let k = match kind {
                        Kind::Tet => BoxCells::Tet,
                        Kind::Hex => BoxCells::Hex,
                        Kind::Prism => BoxCells::Wedge,
                    };
                    if size.len() != 3 || cells.len() != 3 {
                        bail!("--size and --cells take three comma-separated values");
                    }
                    (
                        box_mesh([size[0], size[1], size[2]], [cells[0], cells[1], cells[2]], k)?,
                        output,
                    )
                }
            };
            eprop_io::write_mesh(&mesh, &out)?;
            println!("{}: {} nodes, {} cells", out.display(), mesh.n_nodes(), mesh.n_cells());
        }
    }
    Ok(())
}
