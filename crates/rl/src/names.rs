//! Names of the tensors that cross process boundaries: the learner names them when it exports
//! weights and checkpoints, actors and the selector find them by these names. A network `N`
//! exports its layers as `N.<layer>.weight` and `N.<layer>.bias` (see `terl_nn::Mlp::export`).

/// The policy network (actors act with it).
pub const POLICY: &str = "policy";
/// The two critics (the selector's PTR scoring reads them).
pub const CRITICS: [&str; 2] = ["qf1", "qf2"];
/// TEP's reachability network F (`obs, goal → distance`).
pub const TEP_F: &str = "tep_f";
/// TEP's action network AN (`obs, goal → action`).
pub const TEP_AN: &str = "tep_an";
/// Target copies of F and AN (learner checkpoints only).
pub const TEP_F_TARGET: &str = "tep_f_target";
/// Target copy of AN (learner checkpoints only).
pub const TEP_AN_TARGET: &str = "tep_an_target";
/// The guidance gate in the planner weights message: one 0/1 per task (validated).
pub const TEP_GATE: &str = "tep_gate.validated";
/// Task index of each goal state of the goal library (planner weights message).
pub const TEP_GOAL_TASKS: &str = "tep_goals.tasks";
/// The goal library's states, `[n, obs_dim]` (planner weights message).
pub const TEP_GOAL_STATES: &str = "tep_goals.states";

/// Whether `tensor` is one of network `net`'s tensors (`net.<layer>.…`); `tep_f_target.0.bias`
/// is not one of `tep_f`'s.
pub fn belongs_to(tensor: &str, net: &str) -> bool {
    tensor
        .strip_prefix(net)
        .is_some_and(|rest| rest.starts_with('.'))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tensor_belongs_only_to_the_network_named_before_its_first_dot() {
        assert!(belongs_to("tep_f.0.weight", TEP_F));
        assert!(!belongs_to("tep_f_target.0.weight", TEP_F));
        assert!(!belongs_to("tep_an.0.weight", TEP_F));
        assert!(belongs_to("tep_an.2.bias", TEP_AN));
        assert!(!belongs_to("tep_f", TEP_F));
    }
}
