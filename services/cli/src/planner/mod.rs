//! `terl planner dataset | train | eval`: the planner offline, where it can be measured in
//! minutes. The same code paths as the learner: [`terl_rl::TepBuffer`] for hindsight sampling,
//! [`terl_rl::Tep::update`] for training, [`terl_rl::Planner`] for inference, the TEP dataset
//! MCAP format of the selector (`terl_telemetry::TepDatasetWriter`).

mod dataset;
mod eval;
mod files;
mod train;

use anyhow::Result;
use clap::Subcommand;
use std::process::ExitCode;

#[derive(Debug, Subcommand)]
pub enum PlannerCommand {
    /// Write trajectories in the TEP dataset format (MCAP) from Meta-World's scripted policies.
    Dataset(dataset::DatasetArgs),
    /// Train F and AN offline on TEP datasets; writes a planner file (safetensors).
    Train(train::TrainArgs),
    /// Score a planner on held-out trajectories: F against the true step gaps (Spearman ρ,
    /// relative error by gap), and AN alone in the real environment beside random actions.
    Eval(eval::EvalArgs),
}

pub fn run(command: PlannerCommand) -> Result<ExitCode> {
    match command {
        PlannerCommand::Dataset(a) => dataset::run(a),
        PlannerCommand::Train(a) => train::run(a),
        PlannerCommand::Eval(a) => eval::run(a),
    }
}
