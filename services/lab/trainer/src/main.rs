//! `trainer`: step one of the two-step learning, in one process. See `trainer --help`. Output stops
//! quietly when its reader goes away (`trainer ... | head -1`: see `cli`).

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use config::Eyes;
use config::{Dof, PerDof, Preset};
use learning::Algorithm;
use learning::checkpoint::Checkpoint;
use std::path::PathBuf;
use std::time::Instant;
use trainer::Setup;
use trainer::evaluation::{evaluate, load_policies, policy_checkpoint, save_policies};
use trainer::experiment::{self, Curve};
use trainer::figures::{Alphas, Fig5, PolicyMap, write_json};
use trainer::progress::Progress;
use trainer::step_two_bench::{BenchFile, BenchParams, Shard, Timing, evaluation_json};
use trainer::twin_limit::{LimitGains, SearchParams};
use trainer::world::{EpisodeResult, World};

#[derive(Parser)]
#[command(
    version,
    about = "Two-step NAC learning for cable tracking in one process: step one's experiments in simulation, the twin's limit, step two against the twin, the report."
)]
struct Cli {
    /// Directory holding scenario.toml and learning.toml.
    #[arg(long, global = true, default_value = "config")]
    config: PathBuf,
    /// Learning parameters: `default` (swept learning rates) or `paper` (NAC alpha = 0.01).
    #[arg(long, global = true, default_value = "default")]
    preset: Preset,
    /// How the behaviours see the cable: the exact geometry, or rendered images and perception.
    #[arg(
        long,
        global = true,
        default_value = "ideal",
        value_name = "ideal|images"
    )]
    eyes: Eyes,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The paper's Fig. 5: NAC against Baxter and Bartlett's policy gradient over independent runs.
    Fig5 {
        #[arg(long, default_value_t = 100)]
        runs: usize,
        #[arg(long, default_value_t = 100)]
        episodes: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value = "out/fig5")]
        out: PathBuf,
        /// Episodes over which the LQR limit's mean return is measured.
        #[arg(long, default_value_t = 4000)]
        limit_episodes: usize,
    },
    /// The learning-rate sweep behind the defaults of config/learning.toml.
    Sweep {
        #[arg(long, default_value = "nac")]
        algorithm: Algorithm,
        #[arg(long, default_value_t = 20)]
        runs: usize,
        #[arg(long, default_value_t = 100)]
        episodes: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Comma-separated learning rates (default: a log grid suited to the algorithm).
        #[arg(long, value_delimiter = ',')]
        alphas: Vec<f64>,
        /// Override NAC's natural-gradient damping for this sweep.
        #[arg(long)]
        damping: Option<f64>,
        #[arg(long, default_value = "out/sweep")]
        out: PathBuf,
    },
    /// Step one: learn both behaviours in simulation and write the checkpoint step two loads.
    Train {
        #[arg(long, default_value_t = 100)]
        episodes: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value = "out/step-one.ckpt")]
        checkpoint: PathBuf,
        #[arg(long, default_value = "nac")]
        algorithm: Algorithm,
        /// Also save the checkpoint every this many episodes (0: only at the end).
        #[arg(long, default_value_t = 0)]
        every: usize,
        /// Print a progress line every this many episodes.
        #[arg(long, default_value_t = 10)]
        log_every: usize,
    },
    /// Figs. 6 and 7: each policy's state-to-action map, from a checkpoint, as PNG and JSON.
    PolicyMap {
        #[arg(long)]
        checkpoint: PathBuf,
        #[arg(long, default_value = "out/policy-map")]
        out: PathBuf,
        /// Cells per axis.
        #[arg(long, default_value_t = 41)]
        cells: usize,
    },
    /// The mean return of fixed gains (no learning) under the task's resets and exploration noise.
    Evaluate {
        /// Sway gain K (x_g, dx_g/dt), e.g. `7.7,9.2`.
        #[arg(
            long,
            value_delimiter = ',',
            required = true,
            allow_negative_numbers = true
        )]
        sway: Vec<f64>,
        /// Yaw gain K (Theta, dTheta/dt).
        #[arg(
            long,
            value_delimiter = ',',
            required = true,
            allow_negative_numbers = true
        )]
        yaw: Vec<f64>,
        #[arg(long, default_value_t = 2000)]
        episodes: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Benchmarks: simulated steps per second of one learner pair plus the model (single thread), and
    /// the wall time of the full Fig. 5 experiment; medians over repeats.
    Bench {
        #[arg(long, default_value_t = 5)]
        repeats: usize,
        /// Episodes per single-thread measurement.
        #[arg(long, default_value_t = 200)]
        episodes: usize,
    },
    /// The two-step job's report (Markdown and PNG) from the runs in a directory (see
    /// scripts/two-step-learning).
    Report {
        #[arg(long)]
        dir: PathBuf,
    },
    /// The twin's limit: each DOF's best return a linear policy can have on a twin, by direct policy
    /// search over all four gains on the twin in one process (the cross-entropy method from the LQR
    /// gains, common random numbers), written as two policy directories, each DOF's pair
    /// (DIR/sway/ and DIR/yaw/, each with sway.ckpt and yaw.ckpt: `--initial` loads one), and
    /// DIR/limit.json (gains, returns, the evaluation set, the check). Search with the eyes the
    /// evaluations use (`--eyes images` for the vehicle's perception): a limit found with other eyes
    /// is no limit for them. Policies given as candidates (`--candidate`, `--session`; from the LQR
    /// gains, the LQR gains halved and quartered too) join the search's first generation and are
    /// checked against the limit on the evaluation set: where one evaluates above it by more than
    /// twice the evaluation's noise, the search goes on from it (up to `--rounds` rounds), and
    /// limit.json says which still beats it.
    TwinLimit {
        /// The twin's reality gap.
        #[arg(long, default_value = "config/twin.toml")]
        twin: PathBuf,
        #[arg(long, default_value = "out/twin-limit")]
        out: PathBuf,
        /// The evaluation set's seed (the step-two run's `--seed`): where the limit is reported.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// The search set's seed [default: derived from --seed].
        #[arg(long)]
        search_seed: Option<u64>,
        /// Candidates per generation.
        #[arg(long, default_value_t = 12)]
        population: usize,
        /// Generations at most.
        #[arg(long, default_value_t = 16)]
        generations: usize,
        /// Trials of the search set (distinct start marks).
        #[arg(long, default_value_t = 10)]
        search_trials: u32,
        /// Start from this policy directory's gains instead of the LQR gains.
        #[arg(long, value_name = "DIR")]
        start: Option<PathBuf>,
        /// A policy directory the limit must not be below, named (repeatable; the main job: the
        /// simulation policy first, step two's last).
        #[arg(long, value_name = "NAME=DIR")]
        candidate: Vec<String>,
        /// Step two's run record (the monitor's run.json): every policy its evaluations judged is a
        /// candidate too.
        #[arg(long, value_name = "RUN.json")]
        session: Option<PathBuf>,
        /// Held-out evaluation sets (other starts, floors and noise): the limit and every
        /// `--candidate` are evaluated on them too, with the cables they lose, and the search's
        /// start; the largest spread over them of a difference between two of those policies is the
        /// evaluation's noise the check allows (none under 2 sets: any margin beats the limit).
        #[arg(long, default_value_t = 0)]
        held_out: u32,
        /// Rounds of the search at most.
        #[arg(long, default_value_t = 3)]
        rounds: usize,
    },
    /// Step two over many seeds in one process: step one in simulation, then a learning session on
    /// the twin (the vehicle mesh's algorithm), measured by the evaluation protocol against the
    /// simulation policy and the twin's limit. Seeds run in parallel (a thread each, as many at once
    /// as cores), and the rows do not depend on it. Prints a table; writes JSON. `--shard K/N` runs
    /// every N-th seed from the K-th and writes its JSON; `step-two-merge` puts the N files together
    /// into the file and table of the whole run.
    StepTwoBench {
        /// Seeds: a list (1,2,5) or a range (1..12).
        #[arg(long, default_value = "1..12")]
        seeds: String,
        #[arg(long, default_value = "config/twin.toml")]
        twin: PathBuf,
        /// The twin's limit (a `twin-limit` directory); without it, it is searched first (the same
        /// search in every shard: search it once with `trainer twin-limit` and pass it to all).
        #[arg(long, value_name = "DIR")]
        limit: Option<PathBuf>,
        /// Learning trials of step two (a multiple of learning.toml's evaluation.learning_trials).
        #[arg(long, default_value_t = 20)]
        trials: u32,
        #[arg(long, default_value_t = 100)]
        sim_episodes: usize,
        /// How step one sees the cable in simulation [default: --eyes] (the main job's step one
        /// sees images).
        #[arg(long, value_name = "ideal|images")]
        sim_eyes: Option<config::Eyes>,
        /// Independent evaluation sets on which the simulation policy, the final one and the limit
        /// are evaluated again (the evaluation's noise, and the cables lost on other starts).
        #[arg(long, default_value_t = 4)]
        held_out: u32,
        /// Evaluate the policy after every learning trial (the trials to close half the gap).
        #[arg(long)]
        every_trial: bool,
        /// Run only this shard of the seeds: K/N, every N-th seed from the K-th.
        #[arg(long, value_name = "K/N")]
        shard: Option<trainer::step_two_bench::Shard>,
        /// Threads (0: one per core).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// The limit's search: candidates per generation, generations at most, trials of its
        /// search set, rounds of a seed's search at most, and the seed of the bench's search.
        #[arg(long, default_value_t = 12)]
        limit_population: usize,
        #[arg(long, default_value_t = 16)]
        limit_generations: usize,
        #[arg(long, default_value_t = 10)]
        limit_trials: u32,
        #[arg(long, default_value_t = 3)]
        limit_rounds: usize,
        #[arg(long, default_value_t = 1)]
        limit_seed: u64,
        #[arg(long, default_value = "out/step-two-bench.json")]
        json: PathBuf,
    },
    /// Merges the JSON files of a step-two benchmark's shards (`step-two-bench --shard K/N`, every
    /// K from 1 to N) into the JSON and table the unsplit run gives.
    StepTwoMerge {
        /// The shards' files.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        #[arg(long, default_value = "out/step-two-bench.json")]
        json: PathBuf,
    },
    /// A step-two session's plan: for T learning trials, prints `SESSION EVALUATION` (the trials of
    /// the session, learning and evaluation, and the trials of one evaluation) from learning.toml's
    /// [evaluation]; checks that T is a multiple of its learning_trials and, given --twin, that an
    /// evaluation is one round of the twin's start marks.
    Plan {
        #[arg(long)]
        trials: u32,
        #[arg(long)]
        twin: Option<PathBuf>,
    },
    /// The LQR-optimal linear policy of each DOF and its mean return: the yardstick for Fig. 5.
    Limit {
        #[arg(long, default_value_t = 4000)]
        episodes: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Also write the result as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
    },
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => cli::fail("trainer", err.as_ref()),
    }
}

fn run(cli: Cli) -> Result<()> {
    let setup = Setup::load(&cli.config, cli.preset)?.with_eyes(cli.eyes)?;
    match cli.command {
        Command::Fig5 {
            runs,
            episodes,
            seed,
            out,
            limit_episodes,
        } => fig5(&setup, runs, episodes, seed, &out, limit_episodes),
        Command::Sweep {
            algorithm,
            runs,
            episodes,
            seed,
            alphas,
            damping,
            out,
        } => {
            let mut setup = setup;
            if let Some(d) = damping {
                if !(d.is_finite() && d >= 0.0) {
                    bail!("--damping: {d} must be a finite number >= 0");
                }
                setup.learning.nac.damping = d;
            }
            sweep(&setup, algorithm, runs, episodes, seed, alphas, &out)
        }
        Command::Train {
            episodes,
            seed,
            checkpoint,
            algorithm,
            every,
            log_every,
        } => train(
            &setup,
            episodes,
            seed,
            &checkpoint,
            algorithm,
            every,
            log_every,
        ),
        Command::Evaluate {
            sway,
            yaw,
            episodes,
            seed,
        } => {
            if sway.len() != 2 || yaw.len() != 2 {
                bail!("--sway and --yaw each take two gains, e.g. --yaw 10.8,3.3");
            }
            let gains = PerDof {
                sway: [sway[0], sway[1]],
                yaw: [yaw[0], yaw[1]],
            };
            let progress = Progress::new("evaluate", episodes.div_ceil(50) as u64);
            let eval = experiment::evaluate(&setup, gains, episodes, seed, &progress);
            progress.finish();
            for dof in Dof::ALL {
                cli::outln!(
                    "{dof:>4}: K = [{:8.4}, {:8.4}]  mean return {:9.4} ± {:.4}",
                    gains.get(dof)[0],
                    gains.get(dof)[1],
                    eval.mean_return.get(dof),
                    eval.std_error.get(dof)
                )?;
            }
            cli::outln!(
                "cable lost in {:.2}% of {} episodes",
                100.0 * eval.lost_fraction,
                eval.episodes
            )?;
            Ok(())
        }
        Command::PolicyMap {
            checkpoint,
            out,
            cells,
        } => policy_map(&setup, &checkpoint, &out, cells),
        Command::Report { dir } => {
            let path = trainer::report::write(&dir, &setup.scenario)?;
            cli::outln!(
                "wrote {} and {}",
                path.display(),
                dir.join("summary.json").display()
            )?;
            Ok(())
        }
        Command::Bench { repeats, episodes } => bench(&setup, repeats.max(1), episodes.max(1)),
        Command::TwinLimit {
            twin,
            out,
            seed,
            search_seed,
            population,
            generations,
            search_trials,
            start,
            candidate,
            session,
            held_out,
            rounds,
        } => {
            let search = SearchParams {
                population,
                generations,
                trials: search_trials,
                seed: search_seed.unwrap_or_else(|| config::derive_seed(seed, "twin-limit/search")),
                tolerance: SearchParams::default().tolerance,
                eyes: setup.eyes,
            };
            let candidates = candidate
                .iter()
                .map(|c| {
                    c.split_once('=')
                        .filter(|(name, dir)| !name.is_empty() && !dir.is_empty())
                        .map(|(name, dir)| (name.to_owned(), PathBuf::from(dir)))
                        .with_context(|| format!("--candidate {c}: not NAME=DIR"))
                })
                .collect::<Result<Vec<_>>>()?;
            let given = LimitInputs {
                start: start.as_deref(),
                candidates: &candidates,
                session: session.as_deref(),
                held_out,
                rounds,
            };
            twin_limit(&setup, &twin, &out, seed, &search, &given).map(|_| ())
        }
        Command::Plan { trials, twin } => {
            let (session, e) = plan(&setup, trials, twin.as_deref())?;
            cli::outln!("{session} {e}")?;
            Ok(())
        }
        Command::StepTwoBench {
            seeds,
            twin,
            limit,
            trials,
            sim_episodes,
            sim_eyes,
            held_out,
            every_trial,
            shard,
            threads,
            limit_population,
            limit_generations,
            limit_trials,
            limit_rounds,
            limit_seed,
            json,
        } => {
            let params = BenchParams {
                seeds: parse_seeds(&seeds)?,
                trials,
                sim_episodes,
                eyes: setup.eyes,
                sim_eyes: sim_eyes.unwrap_or(setup.eyes),
                held_out,
                every_trial,
                limit_search: SearchParams {
                    population: limit_population,
                    generations: limit_generations,
                    trials: limit_trials,
                    seed: config::derive_seed(limit_seed, "twin-limit/search"),
                    tolerance: SearchParams::default().tolerance,
                    eyes: setup.eyes,
                },
                limit_rounds,
                limit_seed,
            };
            step_two_bench(
                &setup,
                &twin,
                limit.as_deref(),
                &params,
                shard,
                threads,
                &json,
            )
        }
        Command::StepTwoMerge { shards, json } => step_two_merge(&shards, &json),
        Command::Limit {
            episodes,
            seed,
            json,
        } => {
            let progress = Progress::new("limit", episodes.div_ceil(50) as u64);
            let limit = experiment::limit(&setup, episodes, seed, &progress)?;
            progress.finish();
            for dof in Dof::ALL {
                cli::outln!(
                    "{dof:>4}: K = [{:8.4}, {:8.4}]  mean return {:9.4} ± {:.4}",
                    limit.gain.get(dof)[0],
                    limit.gain.get(dof)[1],
                    limit.mean_return.get(dof),
                    limit.std_error.get(dof)
                )?;
            }
            cli::outln!(
                "cable lost in {:.2}% of {} episodes",
                100.0 * limit.lost_fraction,
                limit.episodes
            )?;
            if let Some(path) = json {
                write_json(&path, &limit).with_context(|| format!("writing {}", path.display()))?;
            }
            Ok(())
        }
    }
}

fn fig5(
    setup: &Setup,
    runs: usize,
    episodes: usize,
    seed: u64,
    out: &std::path::Path,
    limit_episodes: usize,
) -> Result<()> {
    if runs == 0 || episodes == 0 {
        bail!("--runs and --episodes must be at least 1");
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let start = Instant::now();
    let mut curves = Vec::new();
    for algorithm in Algorithm::ALL {
        let progress = Progress::new(algorithm.name(), runs as u64);
        let results = experiment::learning_runs(setup, algorithm, runs, episodes, seed, &progress);
        progress.finish();
        curves.push(PerDof {
            sway: Curve::of(&results, Dof::Sway),
            yaw: Curve::of(&results, Dof::Yaw),
        });
        tracing::info!(
            "{algorithm}: {runs} runs x {episodes} episodes, late cable losses {:.1}%",
            100.0 * experiment::late_loss_fraction(&results, 10)
        );
    }
    let progress = Progress::new("limit", limit_episodes.div_ceil(50) as u64);
    let limit = experiment::limit(setup, limit_episodes, seed, &progress)?;
    progress.finish();
    let gpomdp = curves.pop().expect("two algorithms");
    let nac = curves.pop().expect("two algorithms");
    let fig = Fig5 {
        episodes,
        runs,
        seed,
        nac,
        gpomdp,
        limit: limit.mean_return,
        alpha: Alphas {
            nac: setup.alpha(Algorithm::Nac),
            gpomdp: setup.alpha(Algorithm::Gpomdp),
        },
    };
    let json = out.join("fig5.json");
    write_json(&json, &fig).with_context(|| format!("writing {}", json.display()))?;
    let png = out.join("fig5.png");
    fig.figure().save_png(&png)?;
    let elapsed = start.elapsed().as_secs_f64();
    for dof in Dof::ALL {
        let late = (episodes / 10).max(1);
        cli::outln!(
            "{dof:>4}: last {late} episodes' mean return: NAC {:9.4}, OLPOMDP {:9.4}, LQR limit {:9.4}; NAC within 10% of the limit from episode {}",
            fig.nac.get(dof).tail_mean(late),
            fig.gpomdp.get(dof).tail_mean(late),
            fig.limit.get(dof),
            fig.nac
                .get(dof)
                .first_within(*fig.limit.get(dof), 0.1, 5)
                .map_or("-".into(), |e| e.to_string()),
        )?;
    }
    cli::outln!("Fig. 5 ({runs} runs x {episodes} episodes, both algorithms) in {elapsed:.2} s")?;
    cli::outln!("wrote {} and {}", json.display(), png.display())?;
    Ok(())
}

fn train(
    setup: &Setup,
    episodes: usize,
    seed: u64,
    path: &std::path::Path,
    algorithm: Algorithm,
    every: usize,
    log_every: usize,
) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut world = World::new(
        &setup.scenario,
        &setup.learning,
        algorithm,
        setup.perceiver(seed),
        seed,
    );
    let save = |world: &World| -> Result<()> {
        let agents = world.agents();
        let mut ckpt = Checkpoint::single(agents.sway.checkpoint());
        ckpt.insert(agents.yaw.checkpoint());
        ckpt.save(path)
            .with_context(|| format!("saving the checkpoint {}", path.display()))
    };
    let start = Instant::now();
    let mut window: Vec<EpisodeResult> = Vec::new();
    cli::outln!("episode |  yaw return | sway return | lost | yaw K              | sway K")?;
    for e in 1..=episodes {
        window.push(world.run_episode());
        if log_every > 0 && (e % log_every == 0 || e == episodes) {
            let mean = |dof: Dof| {
                window.iter().map(|r| *r.returns.get(dof)).sum::<f64>() / window.len() as f64
            };
            let last = window.last().expect("one episode at least");
            cli::outln!(
                "{e:7} | {:11.3} | {:11.4} | {:4} | [{:7.3}, {:7.3}] | [{:7.3}, {:7.3}]",
                mean(Dof::Yaw),
                mean(Dof::Sway),
                window.iter().filter(|r| r.lost).count(),
                last.gains.yaw[0],
                last.gains.yaw[1],
                last.gains.sway[0],
                last.gains.sway[1],
            )?;
            window.clear();
        }
        if every > 0 && e % every == 0 {
            save(&world)?;
        }
    }
    save(&world)?;
    cli::outln!(
        "{episodes} episodes in {:.2} s; checkpoint written to {}",
        start.elapsed().as_secs_f64(),
        path.display()
    )?;
    Ok(())
}

fn policy_map(
    setup: &Setup,
    path: &std::path::Path,
    out: &std::path::Path,
    cells: usize,
) -> Result<()> {
    let ckpt = Checkpoint::load(path)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut panels = Vec::new();
    let mut maps = Vec::new();
    for dof in [Dof::Sway, Dof::Yaw] {
        let Some(state) = ckpt.get(dof) else {
            tracing::warn!("{} holds no {dof} policy", path.display());
            continue;
        };
        let gain = state.policy.gain;
        let map = PolicyMap::new(dof, gain, &setup.scenario, cells.max(2));
        let fig = if dof == Dof::Sway { "Fig. 6" } else { "Fig. 7" };
        panels.push(map.panel(&format!("{fig}, {dof} policy")));
        maps.push(map);
    }
    if maps.is_empty() {
        bail!("{} holds no policy", path.display());
    }
    let json = out.join("policy-map.json");
    write_json(&json, &maps).with_context(|| format!("writing {}", json.display()))?;
    let png = out.join("policy-map.png");
    plot::Figure::new(panels, 2).save_png(&png)?;
    cli::outln!("wrote {} and {}", json.display(), png.display())?;
    Ok(())
}

fn bench(setup: &Setup, repeats: usize, episodes: usize) -> Result<()> {
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    // Steps per second of one loop on one thread: fixed gains with learning off (the model, the
    // camera geometry, the allocator: the baseline) against both NAC learners on top.
    let steps_per_s = |learning: bool| {
        let mut rates = Vec::new();
        for r in 0..repeats {
            let seed = r as u64 + 1;
            let mut world = if learning {
                World::new(
                    &setup.scenario,
                    &setup.learning,
                    Algorithm::Nac,
                    setup.perceiver(seed),
                    seed,
                )
            } else {
                let gains = PerDof {
                    sway: [7.7, 9.2],
                    yaw: [10.8, 3.3],
                };
                let agents = experiment::fixed_agents(setup, gains, seed);
                World::with_agents(&setup.scenario, agents, setup.perceiver(seed), seed)
            };
            let start = Instant::now();
            let steps: u64 = (0..episodes)
                .map(|_| world.run_episode().steps as u64)
                .sum();
            rates.push(steps as f64 / start.elapsed().as_secs_f64());
        }
        median(rates)
    };
    let baseline = steps_per_s(false);
    let learners = steps_per_s(true);
    cli::outln!("single thread, median of {repeats} runs of {episodes} episodes:")?;
    cli::outln!("  model + camera + allocator, fixed policies: {baseline:>12.0} steps/s")?;
    cli::outln!(
        "  ... with the NAC sway and yaw learners:     {learners:>12.0} steps/s ({:.2}x the baseline's time per step)",
        baseline / learners
    )?;
    let mut walls = Vec::new();
    for r in 0..repeats {
        let start = Instant::now();
        let hidden = Progress::hidden();
        for algorithm in Algorithm::ALL {
            experiment::learning_runs(setup, algorithm, 100, 100, r as u64 + 1, &hidden);
        }
        experiment::limit(setup, 4000, r as u64 + 1, &hidden)?;
        walls.push(start.elapsed().as_secs_f64());
    }
    cli::outln!(
        "full Fig. 5 (100 runs x 100 episodes, NAC and OLPOMDP, plus the limit) on {} cores: median {:.2} s (min {:.2}, max {:.2})",
        std::thread::available_parallelism().map_or(1, |p| p.get()),
        median(walls.clone()),
        walls.iter().copied().fold(f64::INFINITY, f64::min),
        walls.iter().copied().fold(0.0, f64::max),
    )?;
    Ok(())
}

fn sweep(
    setup: &Setup,
    algorithm: Algorithm,
    runs: usize,
    episodes: usize,
    seed: u64,
    alphas: Vec<f64>,
    out: &std::path::Path,
) -> Result<()> {
    let alphas = if alphas.is_empty() {
        default_grid(algorithm)
    } else {
        alphas
    };
    if let Some(bad) = alphas.iter().find(|a| !(a.is_finite() && **a > 0.0)) {
        bail!("--alphas: {bad} is not a positive learning rate");
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let progress = Progress::new("sweep", (alphas.len() * runs) as u64);
    let rows = experiment::sweep(setup, algorithm, &alphas, runs, episodes, seed, &progress);
    progress.finish();
    cli::outln!(
        "{algorithm} learning-rate sweep: {runs} runs x {episodes} episodes per rate (returns: mean over all episodes / over the last quarter)"
    )?;
    cli::outln!("| alpha | yaw mean | yaw late | sway mean | sway late | late losses |")?;
    cli::outln!("|---:|---:|---:|---:|---:|---:|")?;
    for r in &rows {
        cli::outln!(
            "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.1}% |",
            r.alpha,
            r.mean_return.yaw,
            r.late_return.yaw,
            r.mean_return.sway,
            r.late_return.sway,
            100.0 * r.late_lost
        )?;
    }
    let best = experiment::best_alpha(&rows);
    cli::outln!(
        "best (highest late return): yaw {}, sway {}",
        best.yaw,
        best.sway
    )?;
    let path = out.join(format!("sweep-{algorithm}.json"));
    #[derive(serde::Serialize)]
    struct SweepFile<'a> {
        algorithm: Algorithm,
        runs: usize,
        episodes: usize,
        seed: u64,
        rows: &'a [experiment::SweepRow],
        best: PerDof<f64>,
    }
    write_json(
        &path,
        &SweepFile {
            algorithm,
            runs,
            episodes,
            seed,
            rows: &rows,
            best,
        },
    )
    .with_context(|| format!("writing {}", path.display()))?;
    cli::outln!("wrote {}", path.display())?;
    Ok(())
}

/// Log-spaced learning rates, three per decade, over the range where each algorithm's updates go
/// from negligible to unstable on this task.
fn default_grid(algorithm: Algorithm) -> Vec<f64> {
    let (from, to) = match algorithm {
        Algorithm::Nac => (-3, 1),
        Algorithm::Gpomdp => (-4, 0),
    };
    (from * 3..=to * 3)
        .map(|k| 10f64.powf(k as f64 / 3.0))
        .map(|a| (a * 1e6).round() / 1e6)
        .collect()
}

/// `1..12` or `1,2,5`.
fn parse_seeds(text: &str) -> Result<Vec<u64>> {
    let bad = || anyhow::anyhow!("--seeds: `{text}` is neither a range (1..12) nor a list (1,2,5)");
    let seeds: Vec<u64> = if let Some((a, b)) = text.split_once("..") {
        let (a, b): (u64, u64) = (
            a.trim().parse().map_err(|_| bad())?,
            b.trim().parse().map_err(|_| bad())?,
        );
        (a..=b).collect()
    } else {
        text.split(',')
            .map(|s| s.trim().parse().map_err(|_| bad()))
            .collect::<Result<_>>()?
    };
    if seeds.is_empty() {
        bail!("--seeds: `{text}` names no seed");
    }
    if let Some((i, s)) = seeds
        .iter()
        .enumerate()
        .find(|(i, s)| seeds[..*i].contains(s))
    {
        bail!("--seeds: `{text}` names seed {s} twice (at {i})");
    }
    Ok(seeds)
}

fn load_twin(path: &std::path::Path) -> Result<config::TwinParams> {
    Ok(config::load(path)?)
}

/// The evaluation protocol's trials (learning.toml's `evaluation.trials`), which must be some.
fn evaluation_trials(setup: &Setup) -> Result<u32> {
    let e = setup.learning.evaluation.trials;
    if e == 0 {
        bail!(
            "learning.toml: evaluation.trials is 0, but the evaluation protocol needs evaluation trials"
        );
    }
    Ok(e)
}

/// What `trainer twin-limit` checks its limit against, besides the search.
struct LimitInputs<'a> {
    /// Start from this policy directory instead of the LQR gains.
    start: Option<&'a std::path::Path>,
    /// Named policy directories.
    candidates: &'a [(String, PathBuf)],
    /// Step two's run record, whose evaluated policies are candidates too.
    session: Option<&'a std::path::Path>,
    held_out: u32,
    rounds: usize,
}

/// A policy evaluated on the held-out sets: each set's evaluated return, and the cables lost.
#[derive(serde::Serialize)]
struct HeldOut {
    name: String,
    /// The sets' evaluated returns, in the order of the sets.
    returns: PerDof<Vec<f64>>,
    mean: PerDof<f64>,
    lost: u32,
    trials: u32,
}

fn held_out(
    setup: &Setup,
    twin: &config::TwinParams,
    eyes: config::Eyes,
    name: &str,
    policy: &Checkpoint,
    sets: &[u64],
    e: u32,
) -> Result<HeldOut> {
    let evals = trainer::experiment::parallel_map(sets.len(), &Progress::hidden(), |i| {
        evaluate(&setup.scenario, twin, eyes, policy, sets[i], e)
    })
    .into_iter()
    .collect::<Result<Vec<_>, _>>()?;
    let returns = PerDof {
        sway: evals.iter().map(|v| v.mean().sway).collect::<Vec<_>>(),
        yaw: evals.iter().map(|v| v.mean().yaw).collect::<Vec<_>>(),
    };
    Ok(HeldOut {
        name: name.to_owned(),
        mean: PerDof {
            sway: stats::mean(returns.sway.iter().copied()),
            yaw: stats::mean(returns.yaw.iter().copied()),
        },
        returns,
        lost: evals.iter().map(|v| v.lost).sum(),
        trials: evals.iter().map(|v| v.trials).sum(),
    })
}

/// The held-out evaluation sets of the evaluation set `seed` (the benchmark's).
fn held_out_sets(seed: u64, n: u32) -> Vec<u64> {
    (0..n)
        .map(|h| config::derive_seed(seed, &format!("held-out/{h}")))
        .collect()
}

/// The policies a step-two session's evaluations judged after learning (the run record's gains
/// after the trial before each evaluation began), named by the learning trials before them.
fn session_policies(path: &std::path::Path) -> Result<Vec<(String, PerDof<[f64; 2]>)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let run: records::RunRecord =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    let index = |trial: u32| -> Option<usize> {
        if run.episode_numbers.is_empty() {
            Some(trial as usize)
        } else {
            run.episode_numbers.iter().position(|&n| n == trial)
        }
    };
    let mut policies = Vec::new();
    for ev in run.evaluations.iter().filter(|e| e.learning_trials > 0) {
        let mut begin = ev.trial;
        while begin > 0
            && index(begin - 1).is_some_and(|i| run.evaluation.get(i).copied().unwrap_or(false))
        {
            begin -= 1;
        }
        let before = begin
            .checked_sub(1)
            .and_then(index)
            .filter(|&i| i < run.yaw_gain.len() && i < run.sway_gain.len())
            .with_context(|| {
                format!(
                    "{}: no gains recorded before the evaluation ending at trial {}",
                    path.display(),
                    ev.trial
                )
            })?;
        policies.push((
            format!(
                "step two's evaluation after {} learning trials",
                ev.learning_trials
            ),
            PerDof {
                sway: run.sway_gain[before],
                yaw: run.yaw_gain[before],
            },
        ));
    }
    Ok(policies)
}

/// `trainer twin-limit`; returns the limit (each DOF's pair).
fn twin_limit(
    setup: &Setup,
    twin_path: &std::path::Path,
    out: &std::path::Path,
    seed: u64,
    search: &SearchParams,
    given: &LimitInputs,
) -> Result<LimitGains> {
    use trainer::step_two_bench::gains;
    use trainer::twin_limit::{Candidate, Check};
    let twin = load_twin(twin_path)?;
    let e = evaluation_trials(setup)?;
    let (scenario, learning) = (&setup.scenario, &setup.learning);
    let lqr = experiment::lqr_gains(setup)?;
    let start_gains = match given.start {
        Some(dir) => gains(&load_policies(dir)?),
        None => lqr,
    };
    let mut named: Vec<(String, PerDof<[f64; 2]>)> = Vec::new();
    for (name, dir) in given.candidates {
        let c =
            load_policies(dir).with_context(|| format!("--candidate {name}={}", dir.display()))?;
        named.push((name.clone(), gains(&c)));
    }
    if let Some(run) = given.session {
        for (name, g) in session_policies(run)? {
            if !named.iter().any(|(_, other)| *other == g) {
                named.push((name, g));
            }
        }
    }
    if given.start.is_none() {
        named.extend(trainer::twin_limit::softer_starts(lqr));
    }
    for (i, (name, _)) in named.iter().enumerate() {
        if named[..i].iter().any(|(other, _)| other == name) {
            bail!("--candidate {name}: two candidates have this name");
        }
    }
    let started = Instant::now();
    let scored = trainer::experiment::parallel_map(named.len(), &Progress::hidden(), |i| {
        let c = policy_checkpoint(scenario, learning, named[i].1);
        evaluate(scenario, &twin, search.eyes, &c, seed, e).map(|v| Candidate {
            name: named[i].0.clone(),
            gains: named[i].1,
            evaluated: v.mean(),
            lost: v.lost,
        })
    })
    .into_iter()
    .collect::<Result<Vec<_>, _>>()?;
    // The held-out sets: every named directory and the search's start (a policy of other gains than
    // the candidates', as the limit's will be); the noise of the check from all of them.
    let sets = held_out_sets(seed, given.held_out);
    let mut held = Vec::new();
    for (name, dir) in given.candidates.iter().filter(|_| !sets.is_empty()) {
        held.push(held_out(
            setup,
            &twin,
            search.eyes,
            name,
            &load_policies(dir)?,
            &sets,
            e,
        )?);
    }
    if !sets.is_empty() {
        let start = policy_checkpoint(scenario, learning, start_gains);
        held.push(held_out(
            setup,
            &twin,
            search.eyes,
            "start",
            &start,
            &sets,
            e,
        )?);
    }
    let noise = trainer::twin_limit::check_noise(
        &held
            .iter()
            .map(|h| (&h.returns, h.lost))
            .collect::<Vec<_>>(),
    );
    cli::outln!(
        "twin limit on {} ({} perception): cross-entropy search from sway K = {:?}, yaw K = {:?}; {} candidates x {} generations on {} trials; {} policies to be above",
        twin_path.display(),
        search.eyes,
        start_gains.sway,
        start_gains.yaw,
        search.population,
        search.generations,
        search.trials,
        scored.len()
    )?;
    // A search per DOF.
    let progress = Progress::new("twin limit", 2 * search.generations as u64);
    let found = trainer::twin_limit::find(
        scenario,
        learning,
        &twin,
        PerDof::both(start_gains),
        &scored,
        search,
        &Check {
            seed,
            trials: e,
            noise,
        },
        given.rounds,
        &progress,
    )?;
    progress.finish();
    let pairs = found
        .gains()
        .map(|_, g| policy_checkpoint(scenario, learning, *g));
    for dof in Dof::ALL.into_iter().filter(|_| !sets.is_empty()) {
        held.push(held_out(
            setup,
            &twin,
            search.eyes,
            &trainer::report::held_out_limit_name(dof),
            pairs.get(dof),
            &sets,
            e,
        )?);
    }
    let lqr_eval = evaluate(
        scenario,
        &twin,
        search.eyes,
        &policy_checkpoint(scenario, learning, lqr),
        seed,
        e,
    )?;
    for dof in Dof::ALL {
        save_policies(&out.join(dof.to_string()), pairs.get(dof))?;
    }
    let (m, l) = (found.returns(), lqr_eval.mean());
    for dof in Dof::ALL {
        let g = found.get(dof).gains;
        cli::outln!(
            "{dof:>4}: limit {:9.4} with sway K = [{:7.3}, {:7.3}], yaw K = [{:7.3}, {:7.3}]   (LQR: {:9.4})",
            m.get(dof),
            g.sway[0],
            g.sway[1],
            g.yaw[0],
            g.yaw[1],
            l.get(dof)
        )?;
    }
    let rounds = found.rounds();
    cli::outln!(
        "evaluation set: seed {seed}, {e} trials; cable lost by sway's pair in {}, by yaw's in {}; rounds: sway {}, yaw {}; {} policies evaluated in {:.1} s",
        found.lost().sway,
        found.lost().yaw,
        found.get(Dof::Sway).rounds.len(),
        found.get(Dof::Yaw).rounds.len(),
        rounds.iter().map(|r| r.found.evaluations).sum::<usize>(),
        started.elapsed().as_secs_f64()
    )?;
    for dof in Dof::ALL {
        let best = scored
            .iter()
            .max_by(|a, b| a.evaluated.get(dof).total_cmp(b.evaluated.get(dof)));
        let limit = found.get(dof);
        // The candidate whose own gains are the limit, where no round found its return.
        let taken = limit
            .candidate
            .as_ref()
            .map(|c| format!("; the limit is the gains of {c}, no round having found its return"))
            .unwrap_or_default();
        match (&limit.beaten, best) {
            (Some(b), _) => cli::outln!(
                "{dof:>4}: check: BEATEN by {} by {:.4} (noise {:.4}) after {} rounds{taken}",
                b.by,
                b.margin,
                b.noise,
                limit.rounds.len()
            )?,
            (None, _) if limit.candidate.is_some() => {
                cli::outln!("{dof:>4}: check: above every candidate beyond the noise{taken}")?
            }
            (None, Some(c)) => cli::outln!(
                "{dof:>4}: check: above every candidate beyond the noise (best: {} at {:.4}, noise {:.4})",
                c.name,
                c.evaluated.get(dof),
                noise.get(dof)
            )?,
            (None, None) => {}
        }
    }
    for h in &held {
        cli::outln!(
            "held out ({} sets): {:<24} yaw {:9.4}  sway {:9.4}  cable lost in {} of {} trials",
            sets.len(),
            h.name,
            h.mean.yaw,
            h.mean.sway,
            h.lost,
            h.trials
        )?;
    }
    let json = out.join("limit.json");
    write_json(
        &json,
        &serde_json::json!({
            "twin": twin_path,
            "eyes": search.eyes,
            "gains": found.gains(),
            "returns": found.returns(),
            "evaluation": found.0.map(|_, l| evaluation_json(&l.evaluation)),
            "lqr": { "gains": lqr, "evaluation": evaluation_json(&lqr_eval) },
            "search": { "params": search, "rounds": rounds },
            "check": {
                "candidates": scored,
                "noise": noise,
                "beaten": found.beaten(),
                "limit_is_candidate": found.0.map(|_, l| l.candidate.clone()),
            },
            "held_out": { "sets": sets, "policies": held },
        }),
    )
    .with_context(|| format!("writing {}", json.display()))?;
    cli::outln!(
        "wrote {0}/sway/ and {0}/yaw/ (each DOF's limit pair: sway.ckpt, yaw.ckpt) and {1}",
        out.display(),
        json.display()
    )?;
    Ok(found.gains())
}

/// A limit written by `trainer twin-limit`: each DOF's pair, from DIR/sway and DIR/yaw.
fn load_limit(dir: &std::path::Path) -> Result<LimitGains> {
    let pair = |dof: Dof| -> Result<PerDof<[f64; 2]>> {
        let d = dir.join(dof.to_string());
        if !d.is_dir() {
            bail!(
                "{}: no {dof}/ directory: a limit is each DOF's pair in DIR/sway/ and DIR/yaw/, as `trainer twin-limit --out DIR` writes it",
                dir.display()
            );
        }
        Ok(trainer::step_two_bench::gains(&load_policies(&d)?))
    };
    Ok(PerDof {
        sway: pair(Dof::Sway)?,
        yaw: pair(Dof::Yaw)?,
    })
}

/// `trainer step-two-bench`.
fn step_two_bench(
    setup: &Setup,
    twin_path: &std::path::Path,
    limit_dir: Option<&std::path::Path>,
    params: &BenchParams,
    shard: Option<Shard>,
    threads: usize,
    json: &std::path::Path,
) -> Result<()> {
    let twin = load_twin(twin_path)?;
    evaluation_trials(setup)?;
    plan(setup, params.trials, Some(twin_path))?;
    let started = Instant::now();
    let limit = match limit_dir {
        Some(dir) => load_limit(dir)?,
        None => {
            let dir = json.with_extension("limit");
            // As `trainer twin-limit --rounds R` searches it (the shards of a run search it so).
            let given = LimitInputs {
                start: None,
                candidates: &[],
                session: None,
                held_out: 0,
                rounds: params.limit_rounds,
            };
            twin_limit(
                setup,
                twin_path,
                &dir,
                params.limit_seed,
                &params.limit_search,
                &given,
            )?
        }
    };
    let seeds = shard.map_or_else(|| params.seeds.clone(), |s| s.seeds(&params.seeds));
    if seeds.is_empty() {
        bail!(
            "--shard {}: no seed of the {} falls to it",
            shard.expect("only a shard can be empty"),
            params.seeds.len()
        );
    }
    let cores = std::thread::available_parallelism().map_or(1, |p| p.get());
    let threads = if threads == 0 { cores } else { threads };
    let progress = Progress::new("seeds", seeds.len() as u64);
    let results = trainer::step_two_bench::run(
        &setup.scenario,
        &setup.learning,
        &twin,
        &limit,
        params,
        &seeds,
        threads,
        &progress,
    )?;
    progress.finish();
    let file = BenchFile {
        twin: twin_path.to_owned(),
        twin_params: twin,
        scenario: setup.scenario.clone(),
        learning: setup.learning.clone(),
        params: params.clone(),
        limit,
        shard,
        summary: trainer::step_two_bench::summary(&results),
        seeds: results,
        timing: Timing {
            wall_s: started.elapsed().as_secs_f64(),
            threads,
            shards_wall_s: Vec::new(),
        },
    };
    if let Some(s) = shard {
        cli::outln!("shard {s}: seeds {:?}", seeds)?;
    }
    cli::outln!("{}", file.table().trim_end())?;
    write_bench_file(json, &file)?;
    cli::outln!(
        "wrote {} ({:.0} s on {threads} threads)",
        json.display(),
        file.timing.wall_s
    )?;
    Ok(())
}

fn write_bench_file(json: &std::path::Path, file: &BenchFile) -> Result<()> {
    if let Some(dir) = json.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    write_json(json, file).with_context(|| format!("writing {}", json.display()))
}

/// `trainer step-two-merge`.
fn step_two_merge(shards: &[PathBuf], json: &std::path::Path) -> Result<()> {
    let files = shards
        .iter()
        .map(|p| {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            let file: BenchFile = serde_json::from_str(&text)
                .with_context(|| format!("parsing {} (a step-two-bench file?)", p.display()))?;
            Ok((p.display().to_string(), file))
        })
        .collect::<Result<Vec<_>>>()?;
    let merged = trainer::step_two_bench::merge(&files)?;
    cli::outln!("{}", merged.table().trim_end())?;
    write_bench_file(json, &merged)?;
    cli::outln!(
        "wrote {} ({} shards, {:.0} s in all)",
        json.display(),
        files.len(),
        merged.timing.wall_s
    )?;
    Ok(())
}

/// A step-two session of `trials` learning trials: its trials, and those of one evaluation.
fn plan(setup: &Setup, trials: u32, twin: Option<&std::path::Path>) -> Result<(u32, u32)> {
    let e = &setup.learning.evaluation;
    if e.trials > 0 && !trials.is_multiple_of(e.learning_trials) {
        bail!(
            "{trials} learning trials are not a multiple of learning.toml's evaluation.learning_trials ({}): the session would end without evaluating its last trials",
            e.learning_trials
        );
    }
    if let Some(path) = twin {
        let t = load_twin(path)?;
        let (cycle, period) = (t.trials.cycle, e.trials + e.learning_trials);
        if e.trials > 0 && (cycle != e.trials || !period.is_multiple_of(cycle)) {
            tracing::warn!(
                twin = %path.display(),
                cycle,
                evaluation_trials = e.trials,
                learning_trials = e.learning_trials,
                "an evaluation is not one round of the twin's start marks (trials.cycle should equal evaluation.trials and divide evaluation.trials + evaluation.learning_trials): evaluations do not start alike, and compare worse"
            );
        }
    }
    Ok((behaviour::session_trials(e, trials), e.trials))
}
