//! How a behaviour is found by name and built: the [`BehaviourConfig`] the experiment gives it,
//! the [`Register`] trait that ties a behaviour to its typed [`Params`], and the [`Entry`] a
//! registry keeps for it.

use std::collections::BTreeMap;
use std::sync::Arc;

use world::Track;

use crate::behaviour::Behaviour;
use crate::params::{NoParams, ParamInfo, Params};

/// What every behaviour is built from besides its parameters.
#[derive(Clone, Debug, Default)]
pub struct BehaviourConfig {
    /// Robot ids taking part.
    pub robots: Vec<u16>,
    /// Seed for any randomness.
    pub seed: u64,
    /// The parameters as given (`--param key=value`), parsed into the behaviour's typed
    /// [`Params`] when it is built.
    pub params: BTreeMap<String, String>,
    /// The tape layout of the world, as the world file describes it (empty on a bare floor).
    pub track: Arc<Track>,
}

/// A behaviour built from typed parameters: what a registry needs to check its parameters
/// before any robot moves, list them, and build it.
pub trait Register: Behaviour + Sized {
    /// Its parameters, declared with [`params!`](macro@crate::params).
    type Params: Params;

    /// Builds it for this experiment.
    ///
    /// # Errors
    /// A world it cannot run in, or parameters that do not fit the world.
    fn build(params: Self::Params, config: &BehaviourConfig) -> Result<Self, String>;

    /// Checks the parameters against the world without building anything (for example that
    /// named track nodes exist); by default, nothing beyond their declared ranges.
    ///
    /// # Errors
    /// What does not fit, by name.
    fn check(_params: &Self::Params, _config: &BehaviourConfig) -> Result<(), String> {
        Ok(())
    }

    /// Builds it from `config`'s parameters as given, checked as a registry checks them: for
    /// tests and for code that runs one behaviour without a registry.
    ///
    /// # Errors
    /// A parameter refused, or a world it cannot run in.
    fn from_config(config: &BehaviourConfig) -> Result<Self, String> {
        let name = std::any::type_name::<Self>();
        let name = name.rsplit("::").next().unwrap_or(name);
        let p = parsed(name, &config.params)?;
        Self::check(&p, config)?;
        Self::build(p, config)
    }
}

/// A behaviour built, or why not.
pub type Built = Result<Box<dyn Behaviour>, String>;

/// Builds a behaviour from its config, or says what is wrong.
pub type Constructor = fn(&BehaviourConfig) -> Built;

/// `params` parsed into `P`, the error as text naming the behaviour `name`.
fn parsed<P: Params>(name: &str, params: &BTreeMap<String, String>) -> Result<P, String> {
    P::from_pairs(name, params).map_err(|e| e.to_string())
}

/// How an entry's behaviour is made.
#[derive(Clone, Copy, Debug)]
enum Make {
    /// From its typed parameters: `check` fits them to the world, `build` builds it.
    Typed {
        check: fn(&'static str, &BehaviourConfig) -> Result<(), String>,
        build: fn(&'static str, &BehaviourConfig) -> Built,
    },
    /// By a constructor; it takes no parameters.
    Constructor(Constructor),
}

/// One registered behaviour: its name, what it does, the world it is meant for, its parameters,
/// and how it is checked and built.
#[derive(Clone, Copy, Debug)]
pub struct Entry {
    /// Its name.
    pub name: &'static str,
    /// What it does, one line.
    pub description: &'static str,
    /// The world preset it is meant for.
    pub world: &'static str,
    describe: fn() -> Vec<ParamInfo>,
    parse: fn(&'static str, &BTreeMap<String, String>) -> Result<(), String>,
    make: Make,
}

impl Entry {
    /// The entry of `B`.
    pub fn of<B: Register>(
        name: &'static str,
        description: &'static str,
        world: &'static str,
    ) -> Self {
        Self {
            name,
            description,
            world,
            describe: B::Params::describe,
            parse: |name, params| parsed::<B::Params>(name, params).map(drop),
            make: Make::Typed {
                check: |name, cfg| B::check(&parsed(name, &cfg.params)?, cfg),
                build: |name, cfg| Ok(Box::new(B::build(parsed(name, &cfg.params)?, cfg)?)),
            },
        }
    }

    /// The entry of a behaviour that takes no parameters, built by `constructor`.
    pub fn from_fn(
        name: &'static str,
        description: &'static str,
        world: &'static str,
        constructor: Constructor,
    ) -> Self {
        Self {
            name,
            description,
            world,
            describe: NoParams::describe,
            parse: |name, params| parsed::<NoParams>(name, params).map(drop),
            make: Make::Constructor(constructor),
        }
    }

    /// Its parameters, in declaration order.
    pub fn params(&self) -> Vec<ParamInfo> {
        (self.describe)()
    }

    /// Checks parameters' names, types and ranges alone, before a world is chosen (a sweep checks
    /// each of its combinations so).
    ///
    /// # Errors
    /// The first parameter refused, by name, with the accepted keys for an unknown one.
    pub fn check_params(&self, params: &BTreeMap<String, String>) -> Result<(), String> {
        (self.parse)(self.name, params)
    }

    /// Checks `config`'s parameters (names, types, ranges, fit with the world) without building
    /// the behaviour.
    ///
    /// # Errors
    /// The first parameter refused, by name, with the accepted keys for an unknown one.
    pub fn check(&self, config: &BehaviourConfig) -> Result<(), String> {
        match self.make {
            Make::Typed { check, .. } => check(self.name, config),
            Make::Constructor(_) => self.check_params(&config.params),
        }
    }

    /// Builds the behaviour.
    ///
    /// # Errors
    /// A parameter refused, or a world it cannot run in.
    pub fn build(&self, config: &BehaviourConfig) -> Built {
        match self.make {
            Make::Typed { build, .. } => build(self.name, config),
            Make::Constructor(c) => {
                self.check_params(&config.params)?;
                c(config)
            }
        }
    }
}
