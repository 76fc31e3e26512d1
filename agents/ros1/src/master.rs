//! The ROS Master API and Parameter Server API as an XML-RPC [`Handler`]:
//! argument checking and reply shapes here, rules in [`crate::state`],
//! callbacks in [`crate::core`].

use std::sync::Arc;

use configbot_dataplane::EdgeId;

use crate::core::{Core, lock};
use crate::http::{BoxFut, Handler};
use crate::limits::MAX_PARAM_DEPTH;
use crate::params;
use crate::xmlrpc::{MethodCall, Response, Value};

/// Serves the master and parameter APIs from the shared core.
#[derive(Debug)]
pub(crate) struct MasterHandler {
    pub core: Arc<Core>,
}

fn arg(p: &[Value], i: usize, what: &str) -> Result<String, Value> {
    match p.get(i) {
        Some(Value::Str(s)) => Ok(s.clone()),
        Some(other) => Err(Value::ros(
            -1,
            format!("parameter {what} must be a string, got {other:?}"),
            Value::Int(0),
        )),
        None => Err(Value::ros(
            -1,
            format!("missing parameter {what}"),
            Value::Int(0),
        )),
    }
}

fn ok(msg: impl Into<String>, v: Value) -> Value {
    Value::ros(1, msg, v)
}

impl Handler for MasterHandler {
    fn handle(self: Arc<Self>, call: MethodCall) -> BoxFut<Response> {
        Box::pin(async move {
            let v = match self.dispatch(&call.method, &call.params) {
                Ok(v) | Err(v) => v,
            };
            Response::Ok(v)
        })
    }
}

impl MasterHandler {
    fn dispatch(&self, method: &str, p: &[Value]) -> Result<Value, Value> {
        let core = &self.core;
        let caller = arg(p, 0, "caller_id")?;
        let r = match method {
            "getUri" => ok("", Value::str(&core.master_uri)),
            "getPid" => ok("", Value::Int(i64::from(std::process::id()))),
            "lookupNode" => {
                let name = params::resolve(&arg(p, 1, "node_name")?, &caller);
                match lock(&core.state).nodes.get(&name) {
                    Some(api) => ok(format!("node api for [{name}]"), Value::str(api)),
                    None => Value::ros(-1, format!("unknown node [{name}]"), Value::str("")),
                }
            }
            "getSystemState" => ok("current system state", lock(&core.state).system_state()),
            "getPublishedTopics" => {
                let sub = arg(p, 1, "subgraph").unwrap_or_default();
                ok("current topics", lock(&core.state).published_topics(&sub))
            }
            "getTopicTypes" => ok(
                "current system topic types",
                lock(&core.state).topic_types_value(),
            ),
            "registerPublisher" => {
                let topic = params::resolve(&arg(p, 1, "topic")?, &caller);
                let (ty, api) = (arg(p, 2, "topic_type")?, arg(p, 3, "caller_api")?);
                let (subs, fx) = lock(&core.state).register_publisher(&caller, &api, &topic, &ty);
                core.persist();
                core.run_effects(fx);
                core.wake.notify_one();
                ok(
                    format!("Registered [{caller}] as publisher of [{topic}]"),
                    Value::Array(subs.into_iter().map(Value::Str).collect()),
                )
            }
            "unregisterPublisher" => {
                let topic = params::resolve(&arg(p, 1, "topic")?, &caller);
                let api = arg(p, 2, "caller_api")?;
                let (n, fx) = lock(&core.state).unregister_publisher(&caller, &api, &topic);
                core.persist();
                core.run_effects(fx);
                core.wake.notify_one();
                ok(format!("unregistered {n} publisher"), Value::Int(n))
            }
            "registerSubscriber" => {
                let topic = params::resolve(&arg(p, 1, "topic")?, &caller);
                let (ty, api) = (arg(p, 2, "topic_type")?, arg(p, 3, "caller_api")?);
                let id = EdgeId {
                    topic: topic.clone(),
                    subscriber: caller.clone(),
                };
                // Registered and placed under the settings lock: a
                // publisherUpdate for this subscriber (a publisher registering
                // meanwhile) reads the settings after the placement, so it
                // names the adaptor as the reply below does.
                let (place, fx) = {
                    let mut settings = lock(&core.settings);
                    let (pubs, fx) =
                        lock(&core.state).register_subscriber(&caller, &api, &topic, &ty);
                    let place = !settings.contains_key(&id)
                        && configbot_api::policy::adaptable_type(&ty)
                        && (core.placement)(&id, &pubs);
                    if place {
                        settings.insert(id, Default::default());
                    }
                    (place, fx)
                };
                if place {
                    core.persist_adaptors();
                }
                core.persist();
                core.run_effects(fx);
                core.wake.notify_one();
                let list = core.publishers_for(&topic, &caller);
                ok(
                    format!("Subscribed to [{topic}]"),
                    Value::Array(list.into_iter().map(Value::Str).collect()),
                )
            }
            "unregisterSubscriber" => {
                let topic = params::resolve(&arg(p, 1, "topic")?, &caller);
                let api = arg(p, 2, "caller_api")?;
                let n = lock(&core.state).unregister_subscriber(&caller, &api, &topic);
                let id = EdgeId {
                    topic,
                    subscriber: caller.clone(),
                };
                if n > 0 {
                    core.drop_relay(&id);
                }
                core.persist();
                core.wake.notify_one();
                ok(format!("unregistered {n} subscriber"), Value::Int(n))
            }
            "registerService" => {
                let service = params::resolve(&arg(p, 1, "service")?, &caller);
                let (sapi, api) = (arg(p, 2, "service_api")?, arg(p, 3, "caller_api")?);
                let fx = lock(&core.state).register_service(&caller, &api, &service, &sapi);
                core.persist();
                core.run_effects(fx);
                core.wake.notify_one();
                ok(
                    format!("Registered [{caller}] as provider of [{service}]"),
                    Value::Int(1),
                )
            }
            "unregisterService" => {
                let service = params::resolve(&arg(p, 1, "service")?, &caller);
                let sapi = arg(p, 2, "service_api")?;
                let n = lock(&core.state).unregister_service(&caller, &service, &sapi);
                core.persist();
                ok(format!("unregistered {n} service"), Value::Int(n))
            }
            "lookupService" => {
                let service = params::resolve(&arg(p, 1, "service")?, &caller);
                match lock(&core.state).services.get(&service) {
                    Some((_, sapi)) => ok(format!("rosrpc URI: [{sapi}]"), Value::str(sapi)),
                    None => Value::ros(-1, format!("no provider for [{service}]"), Value::str("")),
                }
            }
            _ => return self.dispatch_param(method, &caller, p),
        };
        Ok(r)
    }

    fn dispatch_param(&self, method: &str, caller: &str, p: &[Value]) -> Result<Value, Value> {
        let core = &self.core;
        let r = match method {
            "getParamNames" => ok(
                "Parameter names",
                Value::Array(
                    lock(&core.state)
                        .params
                        .names()
                        .into_iter()
                        .map(Value::Str)
                        .collect(),
                ),
            ),
            "setParam" => {
                let key = params::resolve(&arg(p, 1, "key")?, caller);
                let value = p
                    .get(2)
                    .cloned()
                    .ok_or_else(|| Value::ros(-1, "missing parameter value", Value::Int(0)))?;
                let depth = params::depth(&key, &value);
                if depth > MAX_PARAM_DEPTH {
                    return Err(Value::ros(
                        -1,
                        format!(
                            "parameter {key} nests {depth} levels (namespaces and value); the limit is {MAX_PARAM_DEPTH}"
                        ),
                        Value::Int(0),
                    ));
                }
                let fx = lock(&core.state).set_param(&key, value);
                core.persist();
                core.run_effects(fx);
                ok(format!("parameter {key} set"), Value::Int(0))
            }
            "getParam" => {
                let key = params::resolve(&arg(p, 1, "key")?, caller);
                match lock(&core.state).params.get(&key) {
                    Some(v) => ok(format!("Parameter [{key}]"), v),
                    None => Value::ros(-1, format!("Parameter [{key}] is not set"), Value::Int(0)),
                }
            }
            "hasParam" => {
                let key = params::resolve(&arg(p, 1, "key")?, caller);
                ok(key.clone(), Value::Bool(lock(&core.state).params.has(&key)))
            }
            "deleteParam" => {
                let key = params::resolve(&arg(p, 1, "key")?, caller);
                let fx = lock(&core.state).delete_param(&key);
                match fx {
                    Some(fx) => {
                        core.persist();
                        core.run_effects(fx);
                        ok(format!("parameter {key} deleted"), Value::Int(0))
                    }
                    None => Value::ros(-1, format!("parameter [{key}] is not set"), Value::Int(0)),
                }
            }
            "searchParam" => {
                let key = arg(p, 1, "key")?;
                match lock(&core.state).params.search(caller, &key) {
                    Some(found) => ok(format!("Found [{found}]"), Value::Str(found)),
                    None => Value::ros(
                        -1,
                        format!("Cannot find parameter [{key}] in an upwards search"),
                        Value::str(""),
                    ),
                }
            }
            "subscribeParam" => {
                let api = arg(p, 1, "caller_api")?;
                let key = params::resolve(&arg(p, 2, "key")?, caller);
                let (v, fx) = lock(&core.state).subscribe_param(caller, &api, &key);
                core.persist();
                core.run_effects(fx);
                ok(format!("Subscribed to parameter [{key}]"), v)
            }
            "unsubscribeParam" => {
                let key = params::resolve(&arg(p, 2, "key")?, caller);
                let n = lock(&core.state).unsubscribe_param(caller, &key);
                core.persist();
                ok(format!("Unsubscribe to parameter [{key}]"), Value::Int(n))
            }
            other => Value::ros(-1, format!("unknown method {other}"), Value::Int(0)),
        };
        Ok(r)
    }
}
