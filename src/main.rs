//! The `eprop` command line.

mod cli;
mod guard;

use crate::cli::run::{run_on, Every, RunOptions};
use crate::cli::serve::{serve_on, ServeOptions};
use crate::cli::{bench, inspect};
use anyhow::{bail, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};
use eprop::distribute::launch::{is_root, launch};
use eprop_io::generate::{box_mesh, cylinder_mesh, BoxCells};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "eprop",
    version,
    about = "Soft-tissue deformation by Poisson energy propagation",
    long_about = "eprop turns a force on an organ into a directional energy source, spreads that energy \
through the volume with a vector Poisson equation (median-dual finite volumes, explicit Euler or \
super-time-stepping or implicit TR-BDF2) \
and moves the nodes with damped dynamics driven by the propagated potential.\n\n\
A run is described by a scenario file (TOML): mesh, material, model, fixed set, loads, time, output.\n\
Results go to one HDF5 file (VTKHDF) that ParaView opens and h5py reads.",
    after_help = "Examples:\n  eprop mesh cylinder -o cyl.msh\n  eprop info cyl.msh\n  eprop run scenarios/cylinder.toml\n  eprop partition cyl.msh --parts 4\n  mpirun -n 2 eprop run scenarios/cylinder.toml --output out.h5"
)]
struct Cli {
    /// More log lines on stderr: -v the setup phases, -vv details, -vvv every solve
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run a scenario to its stop condition and write the HDF5 series.
    #[command(long_about = run_help())]
    Run(RunArgs),
    /// Run a scenario whose live tools and loads a client drives over TCP (docs/protocol.md).
    #[command(
        long_about = "Run a scenario whose live tools and loads (`live = true`) a client drives over \
a TCP socket, and write the HDF5 series as `eprop run` does.\n\n\
The client (scripts/haptic_client.py, or any program speaking docs/protocol.md) sends a hello, then \
tool poses and forces with time stamps, and gets one answer per message at once: the contact force \
and displacement of the latest physics step, extrapolated linearly to the message's time. A client \
of protocol version 2 may also ask for the deformed surface: the outer surface once (rest coordinates, \
node ids, triangles: the surface of `eprop export --surface`), then after its answers the surface \
nodes' displacements of every K-th step, as f32 or f64 (scripts/haptic_client.py --stream K --obj FILE). Physics \
step k (time k dt) waits until the client has sent a sample of every live input at or beyond k dt \
(or bye) and uses the samples interpolated at that time, as `eprop run` does with the same samples \
in a table: a session is reproducible bit for bit. After bye the inputs hold their last samples \
and the run goes on to its stop condition. A malformed message, a second client, or no sample \
within --timeout seconds gets an error message; the run then stops, ends the series with the last \
step computed, and exits with status 1. SIGTERM, SIGINT or SIGHUP stop it the same way with status 3 (also while it waits for the client); a failed write or a full disk with status 4; a state that is no longer finite (NaN or inf) with status 1, as `eprop run` stops. \
Every check of `eprop run` applies (the output claims, the limits on steps, substeps and step sizes, the free space): a refused run \
ends before the `listening on` line. Under mpirun rank 0 holds the socket."
    )]
    Serve(ServeArgs),
    /// Fit scenario parameters (young, coupling, ...) to a measured curve by least squares.
    #[command(
        long_about = "Fit scenario parameters to a measured curve by least squares (bounded \
Levenberg-Marquardt; docs/fit.md).\n\n\
Each curve (--data, repeatable: several curves are fitted at once) is a CSV file: a header row \
naming two columns, x then y, and one row per point with x increasing (blank lines and lines \
starting with # are skipped). A unit in brackets after a name is converted to the scenario's \
units (`indentation (mm)`, `force (mN)`; m, cm, mm, um, N, mN, uN, kN, s, ms, min); a unit eprop \
does not know, or any unit in the paper's unit-free reading, is refused. x is `time` (or `t`), \
`indentation` (the depth of tool --tool in the undeformed organ, the loading branch: the steps \
where the tool is deeper than ever before), or `x`, `y`, `z` (a profile: the rest coordinate \
along a line of nodes, read at the step where the tool is deepest); y is `force` (|F| of tool \
--tool), `displacement` (|u| of the probe of load --load, of node --node ID, or of the \
profile's nodes) or `ux`, `uy`, `uz` (one component). Any other name is refused. \
--data CURVE.csv:KEY=VALUE,... sets that curve's weight=W (default 1), tool=K, load=K, node=ID, \
and a profile's line (the two other rest coordinates, in the x column's unit, e.g. x=1,y=0) and \
tol=. Each curve's residuals are measured relative to a power of two near its largest |y|, \
times sqrt(weight).\n\n\
Each evaluation is a full simulation of the scenario with the parameter values applied as \
--set would apply them (nothing is written); the quantity is sampled at every step and \
interpolated linearly at the curve's x. A curve x outside the simulated range is an error at \
the start and a rejected step later. Under mpirun every process runs every evaluation; the \
fit is the same on any number of processes.\n\n\
Parameters: --param NAME=LO:HI, NAME one of young, beta, conductivity, mass, damping, \
stiffness, coupling, exponent, or a scenario key path (load.1.normal); both bounds positive: \
fitted in log space, from the geometric mean of the bounds (or --start NAME=VALUE). The search \
stops when a step reduces the sum of squares by less than --tolerance (relative), changes \
every parameter by less than it, or after --max-evaluations; one progress line per \
evaluation (on stderr).\n\n\
Report: the fitted values with approximate standard errors (s^2 (J^T J)^-1), the sensitivity \
of each (RMS of value * dy/dvalue over the points), the RMS residual (absolute and relative to \
the data range); printed, and written to PREFIX.json, PREFIX.csv (x, measured, fitted, residual, \
sensitivities) and PREFIX.png (measured against fitted, drawn by scripts/plot_fit.py when python3 \
has matplotlib).\n\n\
Example (a sphere pressed into the cylinder; the force measured against the indentation):\n  printf 'indentation,force\\n0.05,0.11\\n0.10,0.19\\n0.15,0.33\\n0.20,0.55\\n0.25,0.79\\n' > press.csv\n  eprop fit scenarios/cylinder_indent.toml --data press.csv --param young=20:500 -o press_fit\n\n\
Exit status: 0 fitted, 1 error or refusal, 2 bad command line, 3 stopped by a signal."
    )]
    Fit(FitArgs),
    /// Validate a scenario without running it and print what it derives: counts, fixed and
    /// loaded nodes, h, dt, substeps, estimated run time, memory and output size; refuses the
    /// inputs `run` refuses (limits, parameters whose products overflow) and warns as it does
    /// (what `run` would refuse about its output, it prints as a warning).
    Check(CheckArgs),
    /// Describe a mesh: counts, volume, control-volume checks, quality, stable substep and the
    /// nodes and cells that set it.
    Info(InfoArgs),
    /// Convert a mesh: read any supported format, validate, write .msh (Gmsh 4.1), .vtu or .vtkhdf.
    Convert(ConvertArgs),
    /// Split a mesh's node graph for K processes and report the quality of the split.
    #[command(
        long_about = "Split a mesh's node graph for K processes (METIS k-way, as `mpirun -n K eprop run` \
does) and report, for METIS, for PT-Scotch (where the build has it; under `mpirun -n P` it splits \
on P processes, each given a slab of the graph, as `partitioner = \"ptscotch\"` does) and for a \
naive block split of the input numbering side by side, with the time each split took:\n\
  edge cut      graph edges between nodes of different parts (halo traffic)\n\
  imbalance     largest part / mean part (the slowest process sets the pace)\n\
  per part      owned nodes, halo nodes (copies received every substep), neighbour parts"
    )]
    Partition(PartitionArgs),
    /// Measure the propagation kernel against the memory bandwidth (run under mpirun for ranks).
    #[command(
        long_about = "Measure the propagation kernel against the memory bandwidth of this machine.\n\n\
For each generated unit box (N^3 cells, Kuhn tetrahedra) and scheme: node-substeps per second of \
the explicit substep (halo exchange included), the bytes per node a substep must stream at least, \
the bandwidth that implies and its fraction of a STREAM-like triad measured in the same process, \
full steps per second with one substep per step (dt = h), the halo waiting share, the cost of one \
output step and the peak memory per node. Under mpirun every rank takes part: run \
`mpirun -n 2 eprop bench` beside `eprop bench` for the speed-up.\n\n\
Columns: ns/node = ns per node-substep; B/node = bytes per node-substep; frac = GB/s / triad; \
B/node* = peak resident memory per node, all processes."
    )]
    Bench(BenchArgs),
    /// Write a scenario's compact operator L (with its diagonal) as CSR in HDF5, for comparisons.
    #[command(
        long_about = "Write the compact operator L of a scenario (mesh, conductivity, fixed set) as a \
CSR matrix in HDF5: datasets row_ptr, col, val over the nodes in input order, the diagonal \
included (rows of fixed nodes are empty), vol (the free nodes' control volumes V, 0 on fixed \
rows), and attributes h (the substep eprop would use), nodes, dt (the mechanics step) and theta. \
One explicit substep is x <- x + h L x; the implicit integrator solves (V - theta dt V L) x = b. \
scripts/bench_petsc.py and scripts/bench_ksp.py time them with PETSc.\n\n\
An existing output file is replaced only with --overwrite; the output is never one of the \
scenario's inputs nor a series a run is writing. Under mpirun rank 0 builds and writes the file."
    )]
    ExportOperator(ExportOperatorArgs),
    /// The deformed outer surface of a series' steps as OBJ, STL, PLY or VTU files.
    #[command(
        long_about = "The deformed outer surface of a series' steps (the rest mesh's boundary \
faces, quadrilaterals split in two, moved by each step's displacement) as files a viewer or a \
game engine loads: <prefix>_<step>.obj|stl|ply|vtu, one per output step (all of them, every \
--every-th, or --step N). --scalar FIELD adds a value per vertex (a vector field's magnitude): \
a blue-white-red colour in OBJ (v x y z r g b) and PLY (with the value), point data in VTU.\n\n\
Each file is claimed as a run claims its output: never the series read, nor a file a run is \
writing (through any link), nor anything but a regular file; an existing one is replaced only \
with --overwrite.\n\n\
Example: eprop export out/cylinder.h5 --surface obj --every 10 -o out/frames/cyl --scalar energy"
    )]
    Export(ExportArgs),
    /// Generate a mesh: the paper's cylinder or a box.
    Mesh(MeshArgs),
}

/// The flags of a run that `run` and `serve` share.
#[derive(Args)]
struct RunFlags {
    /// Output file (overrides [output] file; default <scenario stem>.h5 beside the scenario)
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// Number of steps (overrides [time])
    #[arg(long)]
    steps: Option<u64>,
    /// Override a scenario key by its TOML path, as if edited in the file (repeatable):
    /// --set material.conductivity=0.1, --set time.steps=50, --set load.1.normal=2.0 (an
    /// array of tables by its 1-based index); VALUE is a TOML value (a bare word is a
    /// string); the series records the overrides with the scenario text
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Print the summary as JSON
    #[arg(long)]
    json: bool,
    /// No progress lines (nor, in `eprop run`, the notes of a setup longer than 2 s)
    #[arg(long, short)]
    quiet: bool,
    /// Without a terminal (a batch job's log): a progress line every N steps, every T
    /// seconds (30s) or minutes (5m), or never (0); with a terminal a bar. In `eprop run` a
    /// setup that takes longer than 2 s notes what it does (auto's trial steps, the multigrid)
    #[arg(long, value_name = "N|Ts|Tm", default_value = "10s")]
    progress_every: Every,
    /// Replace the series in the output file if there is one (never a file of another kind)
    #[arg(long)]
    overwrite: bool,
    /// Start even when the estimated output exceeds the free space of its disk (the start,
    /// the mesh and first step, and 1 MiB + two steps must still fit); the run then writes
    /// until the disk refuses, and stops with status 4, keeping every complete step
    #[arg(long)]
    force: bool,
}

impl RunFlags {
    /// The run's options: these flags with a run's own `restart` and `fuse`.
    fn options(self, restart: Option<PathBuf>, fuse: Option<eprop::config::Fuse>) -> RunOptions {
        RunOptions {
            output: self.output,
            steps: self.steps,
            quiet: self.quiet || self.json,
            restart,
            overwrite: self.overwrite,
            force: self.force,
            progress_every: self.progress_every,
            fuse,
            sets: self.set,
        }
    }
}

#[derive(Args)]
struct RunArgs {
    /// Scenario file (TOML)
    scenario: PathBuf,
    #[command(flatten)]
    flags: RunFlags,
    /// Continue the series in FILE (the output of an interrupted run of the same scenario and
    /// mesh) from its last complete step; the result is bit for bit the uninterrupted run's
    #[arg(long, value_name = "FILE")]
    restart: Option<PathBuf>,
    /// Substeps per fused sweep: auto or 1 to 16 (overrides [performance] fuse; the same
    /// bits whatever the value)
    #[arg(long)]
    fuse: Option<eprop::config::Fuse>,
}

#[derive(Args)]
struct ServeArgs {
    /// Scenario file (TOML) with at least one `live = true` tool or load
    scenario: PathBuf,
    /// Address to listen on, HOST:PORT (port 0 picks a free port; the chosen one is printed)
    #[arg(long, value_name = "HOST:PORT", value_parser = host_port)]
    listen: String,
    /// Seconds to wait for the client to connect, and for each step's samples
    #[arg(long, default_value_t = 10.0, value_parser = timeout_seconds)]
    timeout: f64,
    #[command(flatten)]
    flags: RunFlags,
}

#[derive(Args)]
struct FitArgs {
    /// Scenario file (TOML)
    scenario: PathBuf,
    /// A measured curve (repeatable: the curves are fitted together): CSV with a header
    /// `x,y`, x one of time, t, indentation, or x, y, z (a profile along a line of nodes at
    /// the tool's deepest step); y one of force, displacement, ux, uy, uz; a unit in brackets
    /// is converted (`indentation (mm)`). CURVE.csv:KEY=VALUE,... sets the curve's own
    /// weight=W (default 1), tool=K, load=K, node=ID, and a profile's line (the two other
    /// rest coordinates, in the x column's unit: y=0.02,z=0.02) and tol=
    #[arg(long, value_name = "CURVE.csv[:KEY=VALUE,...]", required = true)]
    data: Vec<String>,
    /// A fitted parameter and its bounds (repeatable): young=20:500, coupling=0.1:10,
    /// load.1.normal=0.1:2
    #[arg(long = "param", value_name = "NAME=LO:HI", required = true)]
    param: Vec<String>,
    /// A starting value (default: the geometric mean of positive bounds, else the middle)
    #[arg(long = "start", value_name = "NAME=VALUE")]
    start: Vec<String>,
    /// The tool (1-based) whose force or indentation the curve holds
    #[arg(long, default_value_t = 1)]
    tool: usize,
    /// The load (1-based) whose probe displacement the curve holds
    #[arg(long, default_value_t = 1)]
    load: usize,
    /// The node (its id in the mesh file) whose displacement |u| the curve holds
    #[arg(long, value_name = "ID")]
    node: Option<u64>,
    /// Override another scenario key in every evaluation (as eprop run --set)
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Report prefix: PREFIX.json, PREFIX.csv, PREFIX.png (default <curve stem>_fit beside
    /// the curve)
    #[arg(short, long, value_name = "PREFIX")]
    output: Option<PathBuf>,
    /// Most simulations of the search (the final sensitivities may add one per parameter)
    #[arg(long, default_value_t = 100)]
    max_evaluations: usize,
    /// Relative reduction of the sum of squares, and relative parameter change, that end
    /// the search
    #[arg(long, default_value_t = 1e-6, value_parser = relative_tolerance)]
    tolerance: f64,
    /// No PNG (no python3 called)
    #[arg(long)]
    no_plot: bool,
    /// Replace report files that exist (refused otherwise)
    #[arg(long)]
    overwrite: bool,
    /// Print the report as JSON
    #[arg(long)]
    json: bool,
    /// No progress lines
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args)]
struct CheckArgs {
    /// Scenario file (TOML)
    scenario: PathBuf,
    /// Number of steps (overrides [time])
    #[arg(long)]
    steps: Option<u64>,
    /// Override a scenario key by its TOML path, as if edited in the file (repeatable):
    /// --set material.conductivity=0.1, --set time.steps=50, --set load.1.normal=2.0 (an
    /// array of tables by its 1-based index); VALUE is a TOML value (a bare word is a
    /// string); the series records the overrides with the scenario text
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Print JSON
    #[arg(long)]
    json: bool,
    /// Measure auto's candidates on trial steps under the first loads, as `run` does
    /// (without it: their models' estimate, which needs no physics)
    #[arg(long)]
    measure: bool,
}

#[derive(Args)]
struct InfoArgs {
    /// Mesh file (.msh, .vtk, .vtu, .node/.ele, .mesh)
    mesh: PathBuf,
    /// Print JSON
    #[arg(long)]
    json: bool,
    /// Refuse inverted cells instead of reorienting them
    #[arg(long)]
    strict: bool,
}

#[derive(Args)]
struct ConvertArgs {
    /// Input mesh (.msh, .vtk, .vtu, .node/.ele, .mesh)
    input: PathBuf,
    /// Output mesh (.msh, .vtu, or .vtkhdf: the mesh that `eprop partition` reads in slabs under mpirun); never one of the input's files
    output: PathBuf,
    /// Refuse inverted cells instead of reorienting them
    #[arg(long)]
    strict: bool,
    /// Replace OUTPUT if it exists (refused otherwise)
    #[arg(long)]
    overwrite: bool,
}

#[derive(Args)]
struct PartitionArgs {
    /// Mesh file
    mesh: PathBuf,
    /// Number of parts (processes)
    #[arg(long, short = 'k', default_value_t = 2)]
    parts: usize,
    /// Print JSON
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct BenchArgs {
    /// Cells per side of the boxes (nodes = (N+1)^3): 20,45,66,99 give 9k to 1M nodes
    #[arg(long, value_delimiter = ',', default_values_t = [20, 45, 66, 99])]
    cells: Vec<usize>,
    /// Schemes to measure
    #[arg(long, value_delimiter = ',', default_values_t = ["compact".to_string(), "paper".to_string()])]
    schemes: Vec<String>,
    /// Also write the cases as JSON to this file
    #[arg(long)]
    json: Option<PathBuf>,
    /// Substeps per fused sweep: auto (timed on one process, 1 on several) or 1 to 16
    #[arg(long, default_value = "auto")]
    fuse: eprop::config::Fuse,
    /// The AVX2+FMA kernel where the CPU has it (off: the portable kernel)
    #[arg(long, default_value = "on", value_parser = ["on", "off"])]
    simd: String,
    /// Replace the --json file if it exists (refused otherwise)
    #[arg(long)]
    overwrite: bool,
}

#[derive(Args)]
struct ExportOperatorArgs {
    /// Scenario file (TOML); its mesh, material and fixed set define L
    scenario: PathBuf,
    /// Output file (.h5); never one of the scenario's inputs
    #[arg(short, long)]
    output: PathBuf,
    /// Replace the output file if it exists (refused otherwise)
    #[arg(long)]
    overwrite: bool,
}

#[derive(Args)]
struct ExportArgs {
    /// The series (.h5) written by eprop run or serve
    series: PathBuf,
    /// obj, stl, ply or vtu
    #[arg(long, default_value = "obj")]
    surface: String,
    /// Every k-th output step
    #[arg(long, default_value_t = 1, value_parser = at_least_one)]
    every: usize,
    /// One output step only (0 is the first)
    #[arg(long)]
    step: Option<usize>,
    /// A point field to write per vertex: displacement, potential, energy, ...
    #[arg(long)]
    scalar: Option<String>,
    /// Prefix of the files: <prefix>_<step>.<ext> (with --step, a name ending in the
    /// format's extension is the file's own name: -o s.obj)
    #[arg(short, long)]
    output: PathBuf,
    /// Replace files that exist (refused otherwise)
    #[arg(long)]
    overwrite: bool,
    /// The length unit of the written coordinates: m, cm, mm, um, or mesh (the mesh file's own
    /// unit, from the scenario's [mesh] unit or scale). Without it the coordinates are the
    /// series' own: metres in the continuum reading (a mesh read in mm is written in m), the
    /// scenario's units in the paper reading (where --unit is refused). Per-vertex values
    /// (--scalar) stay in the series' units
    #[arg(long, value_name = "UNIT")]
    unit: Option<String>,
}

#[derive(Args)]
struct MeshArgs {
    #[command(subcommand)]
    shape: Shape,
    /// Replace the output file if it exists (refused otherwise)
    #[arg(long, global = true)]
    overwrite: bool,
}

/// `eprop run --help`: what it does, every scenario key (`eprop::config::keys`, the one
/// reference), then what a run reports, refuses and returns.
fn run_help() -> String {
    format!(
        "Run a scenario to its stop condition and write the HDF5 series.\n\n{}\n\n{}",
        eprop::config::keys::KEYS,
        RUN_AFTER_KEYS
    )
}

/// The end of `eprop run --help`.
const RUN_AFTER_KEYS: &str =
    "The summary gives the substep h, the steps, the speed, the largest displacement, the contact\n\
displacement of each load and the state of each tool, and warnings about implausible inputs and\n\
results. Run under mpirun for several processes; --restart FILE continues an interrupted series\n\
from its last complete step (tools included).\n\n\
Safety: an output that is one of the run's inputs is refused; an existing series is replaced\n\
only with --overwrite, any other existing file never; one run writes a file at a time (a lock,\n\
<output>.lock, and an inode lock: links to a series being written are refused too); --restart\n\
refuses a changed scenario, mesh or table; a run whose output would not fit on its disk is refused (--force starts it\n\
anyway). Parameters whose products overflow or underflow (a load's contact stress and energy\n\
density, the coupling's push, the continuum source) are refused when the scenario is read (by\n\
check too); a state that is no longer finite stops the run. SIGTERM, SIGINT and SIGHUP stop the\n\
run after a complete, written step.\n\
Exit status: 0 done, 1 error or refusal (or a state that is no longer finite), 2 bad command\n\
line, 3 stopped by a signal (continue with --restart), 4 the output could not be written\n\
(disk full: free space, then continue with --restart).";

#[derive(Clone, Copy, ValueEnum)]
enum Kind {
    Tet,
    Hex,
    Prism,
    /// Six pyramids per hexahedron around a centre node; tetrahedra on the boundary
    Pyramid,
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
        /// Output file: .msh (Gmsh 4.1, with the tagged faces), .vtu, or .vtkhdf (read in
        /// slabs by the processes of a job; volume cells only, faces are selected by box)
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
        /// Output file: .msh (Gmsh 4.1, with the tagged faces), .vtu, or .vtkhdf (read in
        /// slabs by the processes of a job; volume cells only, faces are selected by box)
        #[arg(short, long)]
        output: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    crate::cli::log_to_stderr(cli.verbose);
    let status = match real_main(cli) {
        Ok(()) => 0,
        Err(e) => match e.downcast_ref::<eprop::Agreed>() {
            Some(a) => {
                // a stop says so itself ("stopped by SIGTERM ...")
                let word = if a.status == eprop::distribute::launch::EXIT_STOPPED {
                    ""
                } else {
                    "error: "
                };
                eprintln!("{word}{}", a.message);
                a.status
            }
            None => {
                eprintln!("error: {e:#}");
                1
            }
        },
    };
    if eprop_series::outcome::stranded() {
        // a file whose write failed is still open (eprop_series::outcome): HDF5's exit handler
        // would close it, writing the metadata of uncommitted steps
        use std::io::Write;
        let _ = std::io::stdout().flush();
        let _ = std::io::stderr().flush();
        // SAFETY: ends the process at once (no destructor or atexit handler)
        unsafe { libc::_exit(status.into()) }
    }
    ExitCode::from(status)
}

/// Prints a report as JSON or as text.
fn print<T: serde::Serialize + std::fmt::Display>(report: &T, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(report)?);
    } else {
        println!("{report}");
    }
    Ok(())
}

fn real_main(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Run(a) => {
            let json = a.flags.json;
            run(&a.scenario, &a.flags.options(a.restart, a.fuse), json)
        }
        Cmd::Serve(a) => {
            let json = a.flags.json;
            let opts = ServeOptions {
                listen: a.listen,
                timeout: a.timeout,
                run: a.flags.options(None, None),
            };
            serve(&a.scenario, &opts, json)
        }
        Cmd::Fit(a) => fit(a),
        Cmd::Check(a) => {
            let opts = RunOptions {
                steps: a.steps,
                sets: a.set,
                ..Default::default()
            };
            print(&inspect::check(&a.scenario, &opts, a.measure)?, a.json)
        }
        Cmd::Info(a) => {
            let m = eprop_io::read_mesh_with(&a.mesh, &eprop_io::ReadOptions { strict: a.strict })?;
            print(&eprop::simulate::mesh_info(&m), a.json)
        }
        Cmd::Convert(a) => convert(&a.input, &a.output, a.strict, a.overwrite),
        Cmd::Partition(a) => {
            // every process reads the mesh (a .vtkhdf mesh: its slab) and takes part in the split
            let slabs = a.mesh.extension().is_some_and(|e| e.eq_ignore_ascii_case("vtkhdf"));
            let report = launch(|world| {
                if slabs {
                    return inspect::partition_report_slabs(&a.mesh, a.parts, world);
                }
                let m = eprop_io::read_mesh(&a.mesh)?;
                inspect::partition_report(&m, a.parts, world)
            })?;
            if let Some(r) = report {
                print(&r, a.json)?;
            }
            Ok(())
        }
        Cmd::Bench(a) => {
            let perf = eprop::config::Performance {
                fuse: a.fuse,
                simd: a.simd == "on",
                ..Default::default()
            };
            bench_boxes(&a.cells, &a.schemes, perf, a.json, a.overwrite)
        }
        Cmd::ExportOperator(a) => {
            // one writer: rank 0 builds and writes the operator, the other processes wait
            let report = launch(|world| {
                eprop::distribute::launch::on_root(world, || {
                    inspect::export_operator(&a.scenario, &a.output, a.overwrite)
                })
            })?;
            if let Some(r) = report {
                println!("{r}");
            }
            Ok(())
        }
        Cmd::Export(a) => {
            let o = crate::cli::export::ExportOptions {
                format: crate::cli::export::Format::parse(&a.surface)?,
                every: a.every,
                step: a.step,
                scalar: a.scalar,
                prefix: a.output,
                overwrite: a.overwrite,
                unit: a.unit,
            };
            export_surface(&a.series, &o)
        }
        Cmd::Mesh(a) => {
            let (mesh, out) = generate(a.shape)?;
            let _lock = eprop::guard::safety::claim_file(&out, "the mesh file (-o)", &[], a.overwrite)?;
            write_mesh_any(&mesh, &out)?;
            println!("{}: {} nodes, {} cells", out.display(), mesh.n_nodes(), mesh.n_cells());
            Ok(())
        }
    }
}

/// `eprop fit`: the fit on one process or under mpirun, its report.
fn fit(a: FitArgs) -> Result<()> {
    let opts = crate::cli::fit::FitOptions {
        data: a.data,
        params: a.param,
        starts: a.start,
        tool: a.tool,
        load: a.load,
        node: a.node,
        sets: a.set,
        prefix: a.output,
        max_evaluations: a.max_evaluations,
        tolerance: a.tolerance,
        quiet: a.quiet || a.json,
        plot: !a.no_plot,
        overwrite: a.overwrite,
    };
    if let Some(r) = launch(|world| crate::cli::fit::fit_on(world, &a.scenario, &opts))? {
        print(&r, a.json)?;
    }
    Ok(())
}

/// `eprop run`: the options checked, the run on one process or under mpirun, its summary.
fn run(scenario: &Path, opts: &RunOptions, json: bool) -> Result<()> {
    if opts.restart.is_some() && opts.output.is_some() {
        bail!("--restart continues the series in its FILE; fix: leave out --output");
    }
    if opts.restart.is_some() && opts.overwrite {
        bail!("--restart continues the series in its FILE and --overwrite replaces it; fix: give one of them");
    }
    if let Some(s) = launch(|world| run_on(world, scenario, opts))? {
        print(&s, json)?;
    }
    Ok(())
}

/// `eprop serve`: the served run, its summary.
fn serve(scenario: &Path, opts: &ServeOptions, json: bool) -> Result<()> {
    if let Some(r) = launch(|world| serve_on(world, scenario, opts))? {
        print(&r, json)?;
    }
    Ok(())
}

// Option values checked as the command line is read, so that a bad value is a bad command
// line (status 2) however it is spelt.

/// `--timeout`: seconds, positive, at most 1e9.
fn timeout_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(t) if t > 0.0 && t <= 1e9 => Ok(t),
        _ => Err("must be a positive number of seconds (at most 1e9); fix: give, say, --timeout 10".into()),
    }
}

/// `--listen`: HOST:PORT, a host and a port of 0 to 65535.
fn host_port(s: &str) -> Result<String, String> {
    match s.rsplit_once(':') {
        Some((host, port)) if !host.is_empty() && port.parse::<u16>().is_ok() => Ok(s.to_string()),
        _ => Err(
            "must be HOST:PORT with a port of 0 to 65535 (0 picks a free one); fix: give, say, --listen 127.0.0.1:7000"
                .into(),
        ),
    }
}

/// `--tolerance`: relative, strictly between 0 and 1.
fn relative_tolerance(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(t) if t > 0.0 && t < 1.0 => Ok(t),
        _ => Err("must be between 0 and 1 (relative); fix: e.g. --tolerance 1e-6".into()),
    }
}

/// A count of at least one (`--every`).
fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err("must be a whole number of at least 1; fix: --every 1 takes every step".into()),
    }
}

/// `eprop convert`: the output claimed (not one of the input's files), the mesh read,
/// validated and written.
fn convert(input: &Path, output: &Path, strict: bool, overwrite: bool) -> Result<()> {
    let inputs: Vec<eprop::config::Input> = eprop_io::mesh_files(input)
        .into_iter()
        .map(|p| eprop::config::Input {
            role: format!("the input mesh ({})", p.display()),
            path: p,
        })
        .collect();
    let _lock = eprop::guard::safety::claim_file(output, "the converted mesh (OUTPUT)", &inputs, overwrite)?;
    let m = eprop_io::read_mesh_with(input, &eprop_io::ReadOptions { strict })?;
    for w in &m.warnings {
        eprintln!("warning: {w}");
    }
    write_mesh_any(&m, output)?;
    println!("{}: {} nodes, {} cells", output.display(), m.n_nodes(), m.n_cells());
    Ok(())
}

/// Writes a mesh by the output's extension: `.vtkhdf` (the mesh the processes of a job read in
/// slabs; it keeps the volume cells, their tags and the node ids, and says so when boundary
/// facets or group names are left out), or what `eprop_io::write_mesh` writes (.msh, .vtu).
fn write_mesh_any(m: &eprop_mesh::Mesh, output: &Path) -> Result<()> {
    if output.extension().is_some_and(|e| e.eq_ignore_ascii_case("vtkhdf")) {
        if !m.facets.is_empty() || !m.group_names.is_empty() {
            eprintln!("warning: {}: a .vtkhdf mesh keeps the volume cells, their tags and the node ids; the boundary facets and group names are left out (select faces by box, sphere or half-space)", output.display());
        }
        eprop_series::vtkhdf::write_mesh_file(m, output)
    } else {
        eprop_io::write_mesh(m, output)
    }
}

/// `eprop bench`: the --json file claimed first (rank 0 writes it), a row per case as it is
/// measured, then the JSON.
fn bench_boxes(
    cells: &[usize],
    schemes: &[String],
    perf: eprop::config::Performance,
    json: Option<PathBuf>,
    overwrite: bool,
) -> Result<()> {
    let (root, cases, _lock) = launch(|world| {
        let root = is_root(world);
        // the --json file is claimed before the measurement (rank 0 writes it)
        let lock = eprop::distribute::launch::on_root(world, || {
            json.as_ref()
                .map(|j| eprop::guard::safety::claim_file(j, "the JSON file (--json)", &[], overwrite))
                .transpose()
        })?
        .flatten();
        if root {
            println!("{}", bench::header());
        }
        let report = |c: &bench::Case| {
            if root {
                println!("{}", bench::row(c));
            }
        };
        Ok((
            root,
            bench::bench(world, cells, schemes, perf, &std::env::temp_dir(), report)?,
            lock,
        ))
    })?;
    if let (true, Some(j)) = (root, json) {
        std::fs::write(&j, serde_json::to_string_pretty(&cases)?)
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", j.display()))?;
    }
    Ok(())
}

/// `eprop export`: the files written and the first and last named.
fn export_surface(series: &Path, o: &crate::cli::export::ExportOptions) -> Result<()> {
    let files = crate::cli::export::export(series, o)?;
    println!(
        "{}: {} file(s), {} .. {}",
        series.display(),
        files.len(),
        files.first().map(|f| f.display().to_string()).unwrap_or_default(),
        files.last().map(|f| f.display().to_string()).unwrap_or_default()
    );
    Ok(())
}

/// The mesh a `mesh` subcommand describes, and where it goes.
fn generate(shape: Shape) -> Result<(eprop_mesh::Mesh, PathBuf)> {
    Ok(match shape {
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
                Kind::Pyramid => BoxCells::PyramidTet,
            };
            if size.len() != 3 || cells.len() != 3 {
                bail!("--size and --cells take three comma-separated values");
            }
            (
                box_mesh([size[0], size[1], size[2]], [cells[0], cells[1], cells[2]], k)?,
                output,
            )
        }
    })
}
