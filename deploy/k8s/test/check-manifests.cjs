// Checks rendered Kubernetes manifests (a JSON array of objects on stdin, from
// check-manifests.sh): each object must be a kind this deployment uses and valid against the
// Kubernetes schema of its apiVersion and kind (kubernetes-models' validators, generated from
// Kubernetes' OpenAPI: types, required fields, enums and formats; like the API server's own
// schemas they do not refuse unknown fields), and the properties the farm relies on must hold. Prints one line
// per object; exits 1 on the first problem, naming the object and the failing path.
"use strict";
const fs = require("node:fs");

const models = {
  "v1/Namespace": "kubernetes-models/v1/Namespace",
  "v1/Secret": "kubernetes-models/v1/Secret",
  "v1/Service": "kubernetes-models/v1/Service",
  "apps/v1/Deployment": "kubernetes-models/apps/v1/Deployment",
  "apps/v1/StatefulSet": "kubernetes-models/apps/v1/StatefulSet",
  "autoscaling/v2/HorizontalPodAutoscaler": "kubernetes-models/autoscaling/v2/HorizontalPodAutoscaler",
  "networking.k8s.io/v1/NetworkPolicy": "kubernetes-models/networking.k8s.io/v1/NetworkPolicy",
};

function fail(message) {
  console.error(`check-manifests: ${message}`);
  process.exit(1);
}

const docs = JSON.parse(fs.readFileSync(0, "utf8"));
const byKind = {};
for (const doc of docs) {
  const key = `${doc.apiVersion}/${doc.kind}`;
  const name = `${key} ${doc.metadata && doc.metadata.name}`;
  if (!(key in models)) fail(`${name}: not a kind this deployment should render`);
  const Model = Object.values(require(models[key])).find((v) => typeof v === "function");
  try {
    new Model(doc).validate();
  } catch (error) {
    fail(`${name}: ${error.message}`);
  }
  (byKind[doc.kind] ||= []).push(doc);
  console.log(`valid ${name}`);
}

// What the farm needs of them.
const one = (kind, name) => {
  const found = (byKind[kind] || []).find((d) => d.metadata.name === name);
  if (!found) fail(`no ${kind} ${name}`);
  return found;
};
const coordinator = one("StatefulSet", "prism-coordinator");
if (coordinator.spec.replicas !== 1) fail("the coordinator must have exactly one replica");
if (!(coordinator.spec.volumeClaimTemplates || []).length) fail("the coordinator needs a PVC");
const c = coordinator.spec.template.spec.containers[0];
if (!c.readinessProbe) fail("the coordinator needs a readiness probe");
const worker = one("Deployment", "prism-worker");
const w = worker.spec.template.spec.containers[0];
if (!(w.lifecycle && w.lifecycle.preStop)) fail("workers need a preStop drain");
const drain = Number((w.args.find((a) => a.startsWith("--drain-timeout=")) || "=0").split("=")[1]);
const grace = worker.spec.template.spec.terminationGracePeriodSeconds;
if (!(drain > 0 && grace > drain)) fail(`grace ${grace} s must exceed the drain timeout ${drain} s`);
for (const d of [coordinator, worker]) {
  const env = d.spec.template.spec.containers[0].env || [];
  if (!env.some((e) => e.name === "PRISM_WORKER_SECRET" && e.valueFrom && e.valueFrom.secretKeyRef))
    fail(`${d.metadata.name}: the worker secret must come from a Secret`);
}
one("Service", "prism-coordinator");
// The policy admits exactly the pods the README names: a peer selector with more labels than
// the one it documents (kustomize's commonLabels added part-of to each) admits no API client
// that carries only prism/api-client.
const policy = one("NetworkPolicy", "prism-coordinator");
for (const rule of policy.spec.ingress || []) {
  for (const peer of rule.from || []) {
    const labels = Object.keys((peer.podSelector && peer.podSelector.matchLabels) || {});
    if (peer.podSelector && labels.length !== 1)
      fail(`NetworkPolicy prism-coordinator: a peer selects on ${labels.join(", ")}, want one label`);
  }
}
const api = (policy.spec.ingress || []).flatMap((r) => r.from || []).filter(
  (p) => p.podSelector && (p.podSelector.matchLabels || {})["prism/api-client"] === "true");
if (api.length < 2) fail("NetworkPolicy prism-coordinator: API clients must reach gRPC and HTTP");
const hpa = one("HorizontalPodAutoscaler", "prism-worker");
if (hpa.spec.scaleTargetRef.name !== "prism-worker") fail("the autoscaler must scale the workers");
console.log(`ok: ${docs.length} objects`);
